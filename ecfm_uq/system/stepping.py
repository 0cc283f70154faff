"""The former home of :func:`march`, kept importable: it lives in :mod:`.time.march`."""

from .time.march import march
from .time.march import warm_start as _warm_start

__all__ = ["_warm_start", "march"]
