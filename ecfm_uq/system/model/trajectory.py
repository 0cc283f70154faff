"""The result of a march and the discrete adjoint of its scheme (paper Eq. discrete_sens)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..._validation import as_finite_array
from ...errors import ConvergenceError
from .thresholds import SolveStatus


@dataclass
class Trajectory:
    """Result of :func:`march` (or of :func:`.integrate`, at its ``t_eval``).

    Attributes
    ----------
    times : (n_steps + 1,) ndarray
    Theta : (n_steps + 1, N, P) ndarray
        States. After a failure the arrays stop at the last converged step, so no
        unconverged state is ever returned.
    lam : (n_steps + 1, C) ndarray
        Constraint forces (zero at t = 0).
    dTheta : (n_steps + 1, N, P, n_eps) ndarray or None
        :math:`\\partial\\Theta_t/\\partial\\epsilon` (Eq. discrete_sens / discrete_sens_ecfm;
        for ``integrate(..., sensitivities=True)`` at ``t_eval``, :mod:`.time.bdf`).
    dlam : (n_steps + 1, C, n_eps) ndarray or None
    success : bool
    message : str
    failed_step : int or None
        Index of the step whose Newton solve failed.
    nit : (n_steps,) ndarray
        Newton iterations per step.
    solver : str
        The linear solver used.
    linear_iterations : list of int
        Krylov iterations of every linear solve (empty for direct solvers).
    status : SolveStatus
        ``CONVERGED``, or why the failed step stopped (:class:`.thresholds.SolveStatus`; the
        same codes whichever path marched).
    plan : SolvePlan or None
        The solve plan that ran: ``plan.path`` (``"generic"``, ``"compiled-p1"``,
        ``"compiled-sg"``) and ``plan.reason``, why (e.g. what kept the march off the
        compiled kernels).
    scheme : str
        The time method (``method=``, :data:`.time.methods.METHODS`): ``"euler"``,
        ``"bdf2"`` or, for
        :func:`.integrate`, ``"bdf"`` (variable order).
    stats : dict or None
        :func:`.integrate` only: steps, rejected steps, residual and Jacobian
        evaluations, factorizations, and ``t_reached``.
    """

    times: np.ndarray
    Theta: np.ndarray
    lam: np.ndarray
    dTheta: np.ndarray | None
    dlam: np.ndarray | None
    success: bool
    message: str
    failed_step: int | None
    nit: np.ndarray
    solver: str = "dense"
    linear_iterations: list = field(default_factory=list)
    _adjoint: object = field(default=None, repr=False)
    status: SolveStatus = SolveStatus.CONVERGED
    plan: object = field(default=None, repr=False)
    scheme: str = "euler"
    stats: dict | None = field(default=None, repr=False)

    def adjoint_gradient(self, g_theta, g_lam=None):
        """Gradient in :math:`\\epsilon` of :math:`z = \\sum_t z_t(\\Theta_t, \\lambda_t)` by the
        discrete adjoint of the march's scheme (needs ``march(..., keep_factors=True)``).

        Backward in time, with :math:`A_t` the (augmented) step Jacobian and the step
        rules :math:`(h_s, w_s)` of :mod:`.time.base` (backward Euler: :math:`h = \\Delta t`,
        :math:`w = (1)`),

        .. math::

            A_t^T\\mu_t = \\frac{\\partial z}{\\partial(\\Theta_t, \\lambda_t)}
                + \\sum_{j} w_{t+j,j}\\begin{bmatrix}(M/h_{t+j})^T\\mu_{t+j+1,\\Theta}
                \\\\0\\end{bmatrix},
            \\qquad
            \\frac{dz}{d\\epsilon} = -\\sum_t
                \\Bigl(\\frac{\\partial R_t}{\\partial\\epsilon}\\Bigr)^T\\mu_{t,\\Theta},

        one transposed solve per step with the factors kept from the forward march,
        whatever the number of parameters (the forward sensitivities of Eq.
        discrete_sens need ``n_eps`` right-hand sides per step).

        Parameters
        ----------
        g_theta : (n_steps + 1, N, P) array_like
            :math:`\\partial z/\\partial\\Theta_t` (row 0 is ignored: the initial state
            does not depend on :math:`\\epsilon`).
        g_lam : (n_steps + 1, C) array_like, optional
            :math:`\\partial z/\\partial\\lambda_t` (constrained marches).

        Returns
        -------
        (n_eps,) ndarray
        """
        if self._adjoint is None:
            raise ValueError("march with keep_factors=True to compute adjoint gradients")
        if not self.success:
            raise ConvergenceError(f"adjoint of a failed march: {self.message}")
        n_t, N, P = self.Theta.shape
        g_theta = as_finite_array("g_theta", g_theta, shape=(n_t, N, P)).reshape(n_t, N * P)
        C = self.lam.shape[1]
        if C:
            g_lam = np.zeros((n_t, C)) if g_lam is None else g_lam
            g_lam = as_finite_array("g_lam", g_lam, shape=(n_t, C))
            g_theta = np.concatenate([g_theta, g_lam], axis=1)
        elif g_lam is not None:
            raise ValueError("`g_lam` is only defined for a march under a data constraint")
        return self._adjoint(g_theta)


def generic_adjoint(system, eps, Theta, times, factors, mass_T, rules):
    """The backward pass of :meth:`Trajectory.adjoint_gradient` with kept factors.

    ``rules[s] = (h_s, w_s)``: step ``s`` solves
    :math:`(M/h_s)(\\Theta_{s+1} - \\sum_j w_{s,j}\\Theta_{s-j}) + R(\\Theta_{s+1}) = 0`
    (:mod:`.time.base`), so its multiplier reaches back to every state it combines.
    Returns ``adjoint(g)``, ``g`` of shape (n_t, NP + C) holding
    :math:`\\partial z/\\partial(\\Theta_t, \\lambda_t)`.
    """
    n = Theta[0].size

    def adjoint(g):
        grad = np.zeros(system.n_eps)
        carry = np.zeros((len(times), n))
        for t in range(len(times) - 1, 0, -1):
            rhs = g[t].copy()
            rhs[:n] += carry[t]
            mu = factors[t - 1].solve_transpose(rhs)[:n]
            grad -= system.eps_vjp(Theta[t], eps, mu, times[t])
            h, w = rules[t - 1]  # the step that produced state t
            for j, wj in enumerate(w):
                if t - 1 - j >= 1:  # the initial state does not depend on eps
                    carry[t - 1 - j] += mass_T(mu, h) if wj == 1.0 else wj * mass_T(mu, h)
        return grad

    return adjoint
