"""How an objective's gradient in the parameters is computed: the one place that chooses.

``"forward"``: forward sensitivities :math:`\\partial\\Theta/\\partial\\epsilon` (paper Eqs.
discrete_sens, discrete_sens_ecfm): ``n_eps`` right-hand sides per solve with the
factorized Jacobian. ``"adjoint"``: one transposed solve per solve whatever ``n_eps``
(:meth:`~ecfm_uq.system.SteadySolution.adjoint_gradient`,
:meth:`~ecfm_uq.system.Trajectory.adjoint_gradient`). ``"auto"``: the adjoint when
``n_eps`` exceeds the number of outputs (one, for a scalar objective).
"""

from __future__ import annotations

from ..._validation import check_choice

GRADIENTS = ("auto", "forward", "adjoint")

__all__ = ["GRADIENTS", "choose_gradient"]


def choose_gradient(gradient, n_eps, n_outputs=1):
    """Resolve ``gradient`` to ``"forward"`` or ``"adjoint"``."""
    check_choice("gradient", gradient, GRADIENTS)
    if gradient == "auto":
        return "adjoint" if n_eps > n_outputs else "forward"
    return gradient
