"""The table of the family's methods, ``{name: Stepper}``, and the ``method=`` vocabulary.

======== ===================== ======= ============================== ==================
name     stepper               order   steps                          entry point
======== ===================== ======= ============================== ==================
euler    :class:`BackwardEuler` 1      fixed or given grid            ``march``
bdf2     :class:`BDF2`          2      fixed or given grid            ``march``
bdf      :class:`VariableBDF`   1 - 5  chosen to a tolerance          ``integrate``
======== ===================== ======= ============================== ==================

``method=`` names the method in ``march``, ``integrate`` and ``choose_steps``; ``march``
and ``choose_steps`` also take the older ``scheme=`` (the same names, no change in
behaviour).
"""

from __future__ import annotations

from .bdf import VariableBDF
from .bdf2 import BDF2
from .euler import BackwardEuler

__all__ = [
    "ADAPTIVE",
    "FIXED",
    "METHODS",
    "check_method",
    "grid_rules",
    "method_order",
    "step_rule",
]

#: every method of the family by its ``method=`` name
METHODS = {"euler": BackwardEuler(), "bdf2": BDF2(), "bdf": VariableBDF()}
#: the methods that march a fixed or given grid (``march``, ``choose_steps``)
FIXED = tuple(name for name, m in METHODS.items() if not m.adaptive)
#: the names ``integrate`` takes (``"auto"``: ``"bdf"``)
ADAPTIVE = ("auto", *(name for name, m in METHODS.items() if m.adaptive))


def check_method(method=None, scheme=None, *, default="euler", adaptive=False):
    """The method name from ``method=`` or its alias ``scheme=``, else a ``ValueError``.

    Parameters
    ----------
    method, scheme : str or None
        The two spellings; at most one may be given (``None``: ``default``).
    default : str
    adaptive : bool
        Check against :data:`ADAPTIVE` (``integrate``) instead of :data:`FIXED`.
    """
    if method is not None and scheme is not None and method != scheme:
        raise ValueError(
            f"pass the method once: `method`={method!r} and its alias `scheme`={scheme!r} "
            "disagree (use method=)"
        )
    key = "scheme" if method is None and scheme is not None else "method"
    name = method if method is not None else scheme if scheme is not None else default
    choices = ADAPTIVE if adaptive else FIXED
    if not isinstance(name, str) or name not in choices:
        hint = (
            "fixed steps: march(..., method='bdf2')"
            if adaptive
            else "for error-controlled steps use ecfm_uq.system.integrate(..., rtol=...)"
        )
        raise ValueError(f"`{key}` must be one of {choices}, got {name!r}; {hint}")
    return name


def method_order(method):
    """The order of accuracy of a fixed-grid ``method``."""
    return METHODS[check_method(method)].order


def step_rule(method, s, dt):
    """``(h_s, w_s)`` of step ``s`` of ``method`` on the uniform grid of step ``dt``."""
    return METHODS[method].rule(s, dt)


def grid_rules(method, times):
    """``[(h_s, w_s)]`` of every step of ``method`` on the given grid ``times``."""
    return METHODS[method].rules(times=times)
