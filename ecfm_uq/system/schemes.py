"""The former home of the fixed-grid step rules, kept importable: each method is now a
:class:`~.time.base.Stepper` in :data:`.time.methods.METHODS` (:mod:`.time.euler`,
:mod:`.time.bdf2`)."""

from .time.base import check_times
from .time.methods import FIXED, check_method, grid_rules, method_order, step_rule

#: the fixed-grid methods of ``march`` (``.time.methods.FIXED``)
SCHEMES = FIXED

__all__ = ["SCHEMES", "check_scheme", "check_times", "grid_rules", "scheme_order", "step_rule"]


def check_scheme(scheme):
    """``scheme`` if it names a fixed-grid method, else a ``ValueError`` listing them."""
    return check_method(scheme=scheme)


scheme_order = method_order
