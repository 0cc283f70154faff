"""The former home of :func:`march`, kept importable: it lives in :mod:`.time.marching`."""

from .time.marching import march
from .time.marching import warm_start as _warm_start

__all__ = ["_warm_start", "march"]
