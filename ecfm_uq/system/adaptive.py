"""Error-controlled time integration of a Galerkin system: variable-order, variable-step BDF.

:func:`integrate` solves :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, t) = 0`, i.e. in the
chaos coefficients :math:`(M\\otimes\\mathbb E[\\Psi\\Psi^T])\\,\\dot{\\mathrm{vec}\\Theta} =
-\\mathrm{vec} R`, to a local error tolerance, by the numerical differentiation formulas
(NDF) of orders 1 to 5 in Shampine & Reichelt's quasi-constant step-size form (SIAM J.
Sci. Comput. 18, 1997; the form of ``scipy.integrate.BDF``; Hairer & Wanner II, Sec.
III.1 and III.7). With the backward differences :math:`D_j = \\nabla^j\\Theta_n` of the
accepted states, a step of size :math:`h` and order :math:`k` solves for
:math:`\\Theta_{n+1} = \\Theta^{(0)} + d`, :math:`\\Theta^{(0)} = \\sum_{j\\le k} D_j`,

.. math::

    \\frac{M}{c}\\,(d + \\psi) + R(\\Theta^{(0)} + d; \\epsilon, t_{n+1}) = 0, \\qquad
    c = \\frac{h}{\\alpha_k}, \\quad \\psi = \\frac{1}{\\alpha_k}\\sum_{j=1}^k\\gamma_j D_j,

:math:`\\gamma_j = \\sum_{i\\le j} 1/i`, :math:`\\alpha_k = (1 - \\kappa_k)\\gamma_k`. This
is a backward-Euler step of length :math:`c` (the same Jacobian :math:`M/c + J`), so the
solve plan's linear solvers, Krylov methods and preconditioners (:mod:`.linear`) serve it
unchanged; the predictor :math:`\\Theta^{(0)}` (the extrapolated interpolant of the last
states) is the warm start. Newton is the simplified iteration: the Jacobian :math:`J` is
kept from step to step and evaluated again only when the iteration does not converge;
:math:`M/c + J` is factorized again only when :math:`c` changes (after a change of step
size or order, at most every :math:`k + 1` steps).

Error control: the local error estimate is :math:`(\\kappa_k\\gamma_k + 1/(k+1))\\,d`; a
step is accepted when its norm

.. math::

    \\|e\\| = \\Bigl(\\frac{1}{NP}\\sum_{i,\\ell}
        \\Bigl(\\frac{e_{i\\ell}}{\\mathrm{atol} + \\mathrm{rtol}\\,|\\Theta_{i\\ell}|}\\Bigr)^2
        \\Bigr)^{1/2}

over all chaos coefficients is at most 1 (the norm of ``scipy.integrate.solve_ivp``); the
next step size and order (:math:`k - 1`, :math:`k`, :math:`k + 1`) are those that
promise the largest step. Values at ``t_eval`` come from the interpolant of the accepted
step (dense output, of the step's order), so ``t_eval`` does not constrain the steps.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validation import as_finite_array, check_int, check_positive
from ..errors import KrylovError, ModelEvaluationError
from ..threads import library_threads
from .linear import LinearSolver
from .operator import GalerkinOperator
from .options import solver_options
from .plan import NEWTON_ETA_MAX, dense_unknowns
from .thresholds import SolveStatus
from .trajectory import Trajectory

__all__ = ["METHODS", "integrate"]

METHODS = ("auto", "bdf")
MAX_ORDER = 5
NEWTON_MAXITER = 4
MIN_FACTOR, MAX_FACTOR = 0.2, 10.0
# the NDF's kappa (Shampine & Reichelt 1997, Table 1; kappa_5 = 0 makes order 5 a BDF)
KAPPA = np.array([0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415, 0.0])
GAMMA = np.concatenate([[0.0], np.cumsum(1.0 / np.arange(1, MAX_ORDER + 1))])
ALPHA = (1.0 - KAPPA) * GAMMA
ERROR_CONST = KAPPA * GAMMA + 1.0 / np.arange(1, MAX_ORDER + 2)


def _rms(x):
    return float(np.linalg.norm(x) / np.sqrt(x.size))


def _difference_change(order, factor):
    """The matrix taking the differences :math:`D_0..D_k` of step size h to those of
    ``factor * h`` (Shampine & Reichelt 1997, Sec. 2.4): ``D <- (R U)^T D``."""

    def R(f):
        i = np.arange(1, order + 1)[:, None]
        j = np.arange(1, order + 1)
        A = np.zeros((order + 1, order + 1))
        A[1:, 1:] = (i - 1 - f * j) / i
        A[0] = 1.0
        return np.cumprod(A, axis=0)

    return (R(factor) @ R(1.0)).T


def _check_t_eval(t_eval, t0):
    t_eval = np.atleast_1d(as_finite_array("t_eval", t_eval))
    if t_eval.ndim != 1 or t_eval.size < 1:
        raise ValueError(f"`t_eval` must be a 1-D array of times, got shape {t_eval.shape}")
    if np.any(np.diff(t_eval) <= 0):
        k = int(np.nonzero(np.diff(t_eval) <= 0)[0][0])
        raise ValueError(
            f"`t_eval` must be strictly increasing, but t_eval[{k + 1}] = {t_eval[k + 1]:g} "
            f"<= t_eval[{k}] = {t_eval[k]:g}; sort it (np.unique) before integrating"
        )
    t0 = float(t_eval[0]) if t0 is None else float(as_finite_array("t0", t0, ndim=0))
    if t_eval[0] < t0:
        raise ValueError(f"`t_eval` must start at or after t0 = {t0:g}, got {t_eval[0]:g}")
    if t_eval[-1] == t0:
        raise ValueError("`t_eval` must reach beyond t0 (the time of Theta0)")
    return t_eval, t0


class _MassSolve:
    """Solves with :math:`M\\otimes\\mathbb E[\\Psi\\Psi^T]` (for the initial slope only)."""

    def __init__(self, system):
        M = system.M
        try:
            self.lu = spla.splu(sp.csc_matrix(M)) if sp.issparse(M) else None
        except RuntimeError as e:  # splu: "Factor is exactly singular"
            raise _singular_mass(M) from e
        self.M = None if sp.issparse(M) else np.asarray(M)
        self.E2 = system.E2

    def __call__(self, B):  # B (N, P): X with M X E2 = B
        try:
            X = self.lu.solve(B) if self.lu is not None else np.linalg.solve(self.M, B)
        except np.linalg.LinAlgError as e:
            raise _singular_mass(self.M) from e
        return np.linalg.solve(self.E2.T, X.T).T


def _singular_mass(M):
    """The ValueError of a singular mass matrix, with its rank when it is dense."""
    rank = "" if sp.issparse(M) else f" (rank {np.linalg.matrix_rank(M)} < N = {M.shape[0]})"
    return ValueError(
        f"the mass matrix `M` of the system is singular{rank}: integrate() needs an "
        "invertible M (it starts from the slope M^-1 R); for algebraic rows (a DAE) march "
        "on a grid with march(system, eps, Theta0, dt, n_steps) or march(..., times=...), "
        "whose implicit steps allow a singular M, or give every equation a time derivative"
    )


@library_threads(size=dense_unknowns)
def integrate(
    system,
    eps,
    Theta0,
    t_eval,
    *,
    rtol=1e-6,
    atol=None,
    method="auto",
    t0=None,
    first_step=None,
    max_step=np.inf,
    max_steps=100_000,
    solver="auto",
):
    """Integrate :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, t) = 0` to a tolerance.

    Parameters
    ----------
    system : GalerkinSystem
        Must have a mass matrix ``M`` (and no data constraint: for calibration use the
        fixed-step :func:`march`, whose adjoint is exact).
    eps : (n_eps,) array_like
    Theta0 : (N, P) or (N,) array_like
        State at ``t0``.
    t_eval : (n_t,) array_like
        Strictly increasing times at which the state is returned.
    rtol : float
        Relative tolerance of the local error, per chaos coefficient; ``> 0``.
    atol : float or (N, P) array_like, optional
        Absolute tolerance; default ``rtol * max|Theta0|`` (``rtol`` when
        ``Theta0 = 0``), so the result does not depend on the model's units.
    method : {"auto", "bdf"}
        ``"bdf"``: variable-order (1-5) NDF/BDF with error control (module notes).
    t0 : float, optional
        Time of ``Theta0``; default ``t_eval[0]``.
    first_step, max_step : float, optional
        The first step (default: chosen from the slope) and the largest step.
    max_steps : int
        Give up (an unsuccessful result) after this many steps.
    solver : str, SolverOptions or dict
        Linear solver of the step Jacobians :math:`M/c + J`, as for :func:`march`.

    Returns
    -------
    Trajectory
        ``times = t_eval`` and ``Theta`` of shape ``(n_t, N, P)``, ``scheme="bdf"``,
        ``nit`` the Newton iterations of each accepted step and ``stats`` the counts of
        steps, rejected steps, Jacobians and factorizations. When a step cannot meet the
        tolerance (its size falls below round-off of ``t``, or ``max_steps`` is reached)
        ``success`` is ``False``, the message names the time reached and the reason, and
        ``times``/``Theta`` hold every ``t_eval`` reached before it.

    Raises
    ------
    ValueError
        Unknown ``method``, ``rtol <= 0``, ``atol < 0``, ``t_eval`` not increasing, a
        system without mass matrix.
    """
    eps = system.check_eps(eps)
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(
            f"`method` must be one of {METHODS}, got {method!r} (fixed steps: "
            "march(..., scheme='bdf2'))"
        )
    rtol = check_positive("rtol", rtol)
    if rtol < 100 * np.finfo(float).eps:
        raise ValueError(f"`rtol`={rtol:g} is below what double precision can meet; use >= 1e-14")
    t_eval, t0 = _check_t_eval(t_eval, t0)
    max_steps = check_int("max_steps", max_steps, minimum=1)
    if max_step != np.inf:
        max_step = check_positive("max_step", max_step)
    if first_step is not None:
        first_step = check_positive("first_step", first_step)
    if system.M is None:
        system.mass_matrix()  # raises the "no mass matrix" error
    N, P = system.shape
    Theta0 = system.check_initial_state(Theta0)
    if atol is None:
        big = float(np.abs(Theta0).max())
        atol = rtol * (big if big > 0 else 1.0)
    else:
        atol = as_finite_array("atol", atol)
        if atol.shape not in ((), (N, P)) or np.any(atol < 0):
            raise ValueError(f"`atol` must be a non-negative float or an {(N, P)} array")
        atol = atol if atol.shape == () else atol.copy()
    return _BDF(system, eps, Theta0, t_eval, t0, rtol, atol, first_step, max_step, max_steps,
                solver_options(solver)).run()  # fmt: skip


class _BDF:
    """The state of one variable-order BDF integration (see the module notes)."""

    def __init__(self, system, eps, Theta0, t_eval, t0, rtol, atol, first_step, max_step,
                 max_steps, opts):  # fmt: skip
        self.system, self.eps, self.t_eval = system, eps, t_eval
        self.rtol, self.atol, self.max_step, self.max_steps = rtol, atol, max_step, max_steps
        self.N, self.P = system.shape
        self.linear = LinearSolver(system, opts, steady=False, scheme="bdf")
        self.newton_tol = max(10 * np.finfo(float).eps / rtol, min(0.03, rtol**0.5))
        self.t, self.y = t0, Theta0.copy()
        self.stats = dict(n_steps=0, n_rejected=0, n_residuals=0, n_jacobians=0, n_factorizations=0)
        self.first_step = first_step

    # -- model evaluations ---------------------------------------------------------------
    def residual(self, y, t):
        self.stats["n_residuals"] += 1
        return self.system.residual(y, self.eps, None, t)

    def jacobian_parts(self, y, t):
        self.stats["n_jacobians"] += 1
        return self.system.jacobian_operator(y, self.eps, t).parts

    def factorize(self, parts, c):
        self.stats["n_factorizations"] += 1
        if self.system.is_linear:  # the system's cached operator: same object, same factors
            op = self.system.jacobian_operator(self.y, self.eps, self.t, dt=c)
        else:
            op = GalerkinOperator(self.system, parts, dt=c)
        return self.linear.factorize(op)

    def scale(self, y):
        return self.atol + self.rtol * np.abs(y)

    # -- start ---------------------------------------------------------------------------
    def initial_step(self, f0):
        """Hairer, Norsett & Wanner I, Sec. II.4 (as ``scipy.integrate``'s first step)."""
        y0, t0 = self.y, self.t
        scale = self.scale(y0)
        d0, d1 = _rms(y0 / scale), _rms(f0 / scale)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        f1 = -self.mass_solve(self.residual(y0 + h0 * f0, t0 + h0))
        d2 = _rms((f1 - f0) / scale) / h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** 0.5
        return min(100 * h0, h1)

    # -- Newton --------------------------------------------------------------------------
    def newton(self, t_new, y_pred, c, psi, factor, scale):
        """Simplified Newton for :math:`(M/c)(d+\\psi) + R(\\Theta^{(0)}+d) = 0`; returns
        ``(converged, iterations, y, d)``."""
        system = self.system
        d = np.zeros_like(y_pred)
        y = y_pred.copy()
        old = None
        direct = not self.linear.iterative
        for k in range(NEWTON_MAXITER):
            try:
                R = self.residual(y, t_new)
            except ModelEvaluationError:
                return False, k + 1, y, d
            r = system.apply_mass(d + psi) / c + R
            if not np.all(np.isfinite(r)):
                return False, k + 1, y, d
            try:
                dy = -factor.solve(r.ravel(), rtol=NEWTON_ETA_MAX).reshape(self.N, self.P)
            except KrylovError:
                return False, k + 1, y, d
            norm = _rms(dy / scale)
            rate = None if old is None else norm / old
            if rate is not None and (
                rate >= 1 or rate ** (NEWTON_MAXITER - k) / (1 - rate) * norm > self.newton_tol
            ):
                return False, k + 1, y, d
            y += dy
            d += dy
            # a linear system with an exact factorization is solved by the first step
            if (
                norm == 0
                or (direct and system.is_linear)
                or (rate is not None and rate / (1 - rate) * norm < self.newton_tol)
            ):
                return True, k + 1, y, d
            old = norm
        return False, NEWTON_MAXITER, y, d

    # -- the march -----------------------------------------------------------------------
    def run(self):
        system, N, P = self.system, self.N, self.P
        t_eval = self.t_eval
        out = np.zeros((len(t_eval), N, P))
        n_out = 0
        while n_out < len(t_eval) and t_eval[n_out] == self.t:
            out[n_out] = self.y
            n_out += 1
        self.mass_solve = _MassSolve(system)
        t_end = float(t_eval[-1])
        try:
            f0 = -self.mass_solve(self.residual(self.y, self.t))
        except ModelEvaluationError as e:
            return self.result(out, n_out, False, f"model evaluation failed at t0: {e}", [],
                               SolveStatus.MODEL_FAILURE)  # fmt: skip
        h = self.first_step if self.first_step is not None else self.initial_step(f0)
        h = min(float(h), self.max_step, t_end - self.t)
        D = np.zeros((MAX_ORDER + 3, N, P))
        D[0], D[1] = self.y, f0 * h
        order, n_equal = 1, 0
        try:
            parts = None if system.is_linear else self.jacobian_parts(self.y, self.t)
        except ModelEvaluationError as e:
            return self.result(out, n_out, False, f"model evaluation failed at t0: {e}", [],
                               SolveStatus.MODEL_FAILURE)  # fmt: skip
        factor, current_jac = None, True
        nits = []
        while self.t < t_end:
            if self.stats["n_steps"] >= self.max_steps:
                msg = (f"max_steps={self.max_steps} steps reached at t={self.t:.6g} before "
                       f"t_eval[-1]={t_end:g}; raise max_steps or loosen rtol")  # fmt: skip
                return self.result(out, n_out, False, msg, nits, SolveStatus.MAX_ITERATIONS)
            t = self.t
            min_step = 10 * abs(np.nextafter(t, np.inf) - t)
            if h > self.max_step:
                D[: order + 1] = np.tensordot(
                    _difference_change(order, self.max_step / h), D[: order + 1], 1
                )
                h, n_equal, factor = self.max_step, 0, None
            accepted = False
            while not accepted:
                if h < min_step:
                    msg = (
                        f"{system.name}: the step size fell to {h:.3g} at t={t:.6g} "
                        f"(integrated from t={float(t_eval[0]):g} to t_eval[{n_out - 1}]="
                        f"{float(t_eval[max(n_out - 1, 0)]):g}) without meeting rtol={self.rtol:g}"
                        f" (Newton or the error test fails at every step size); the states "
                        "up to t are returned"
                    )
                    return self.result(out, n_out, False, msg, nits, SolveStatus.STEP_SIZE)
                t_new = t + h
                if t_new > t_end:
                    t_new = t_end
                    D[: order + 1] = np.tensordot(
                        _difference_change(order, (t_new - t) / h), D[: order + 1], 1
                    )
                    n_equal, factor = 0, None
                h = t_new - t
                y_pred = D[: order + 1].sum(axis=0)
                scale = self.scale(y_pred)
                psi = np.tensordot(GAMMA[1 : order + 1], D[1 : order + 1], 1) / ALPHA[order]
                c = h / ALPHA[order]
                converged = False
                while not converged:
                    if factor is None:
                        factor = self.factorize(parts, c)
                    if factor is None:  # singular step Jacobian: a smaller step may do
                        break
                    converged, nit, y_new, d = self.newton(t_new, y_pred, c, psi, factor, scale)
                    if not converged:
                        if current_jac or system.is_linear:
                            break
                        try:
                            parts = self.jacobian_parts(y_pred, t_new)
                        except ModelEvaluationError:  # a smaller step may evaluate
                            break
                        factor, current_jac = None, True
                if not converged:
                    h *= 0.5
                    D[: order + 1] = np.tensordot(_difference_change(order, 0.5), D[: order + 1], 1)
                    n_equal, factor = 0, None
                    self.stats["n_rejected"] += 1
                    continue
                safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + nit)
                scale = self.scale(y_new)
                error_norm = _rms(ERROR_CONST[order] * d / scale)
                if error_norm > 1:
                    f = max(MIN_FACTOR, safety * error_norm ** (-1 / (order + 1)))
                    h *= f
                    D[: order + 1] = np.tensordot(_difference_change(order, f), D[: order + 1], 1)
                    n_equal = 0
                    self.stats["n_rejected"] += 1
                    # Newton converged: the factorization is kept only if c is unchanged
                    factor = None
                else:
                    accepted = True
            self.stats["n_steps"] += 1
            nits.append(nit)
            n_equal += 1
            self.t, self.y = t_new, y_new
            current_jac = False
            # the differences of the new state: D^{j+1} y_n = D^j y_n - D^j y_{n-1}
            D[order + 2] = d - D[order + 1]
            D[order + 1] = d
            for i in reversed(range(order + 1)):
                D[i] += D[i + 1]
            # dense output on (t, t_new] by the interpolant through the last order+1 states
            k = n_out + int(np.searchsorted(t_eval[n_out:], t_new, side="right"))
            if k > n_out:
                out[n_out:k] = self.interpolate(t_eval[n_out:k], t_new, h, order, D)
                n_out = k
            if n_equal < order + 1:
                continue
            err_m = _rms(ERROR_CONST[order - 1] * D[order] / scale) if order > 1 else np.inf
            err_p = (
                _rms(ERROR_CONST[order + 1] * D[order + 2] / scale) if order < MAX_ORDER else np.inf
            )
            with np.errstate(divide="ignore"):
                norms = np.array([err_m, error_norm, err_p])
                factors = norms ** (-1.0 / np.arange(order, order + 3))
            order += int(np.argmax(factors)) - 1
            f = min(MAX_FACTOR, safety * float(np.max(factors)))
            h *= f
            D[: order + 1] = np.tensordot(_difference_change(order, f), D[: order + 1], 1)
            n_equal, factor = 0, None
        return self.result(out, n_out, True, "reached t_eval[-1] within the tolerance", nits)

    @staticmethod
    def interpolate(t, t_new, h, order, D):
        """The step's interpolant :math:`\\Theta_{n+1} + \\sum_{j=1}^k D_j \\prod_{i<j}
        (t - t_{n+1} + i h) / ((i + 1) h)` (Shampine & Reichelt 1997) at the times ``t``
        (m,); returns (m, N, P)."""
        i = np.arange(order)
        x = (t[:, None] - (t_new - h * i)) / (h * (1 + i))
        p = np.cumprod(x, axis=1)  # (m, order)
        return D[0] + np.tensordot(p, D[1 : order + 1], 1)

    def result(self, out, n_out, success, message, nits, status=SolveStatus.CONVERGED):
        n = n_out
        return Trajectory(
            self.t_eval[:n].copy(),
            out[:n],
            np.zeros((n, 0)),
            None,
            None,
            success,
            message,
            None,
            np.asarray(nits, dtype=int),
            self.linear.record.solver,
            list(self.linear.record.iterations),
            status=SolveStatus.CONVERGED if success else status,
            plan=self.linear.plan,
            scheme="bdf",
            stats=dict(self.stats, t_reached=self.t),
        )
