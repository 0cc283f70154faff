"""The former home of :func:`integrate`, kept importable: it lives in
:mod:`.time.integration` (the variable-order BDF in :mod:`.time.bdf`)."""

from .time.integration import integrate
from .time.methods import ADAPTIVE

#: the names ``integrate(method=)`` takes
METHODS = ADAPTIVE

__all__ = ["METHODS", "integrate"]
