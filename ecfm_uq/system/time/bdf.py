"""The variable-order, variable-step BDF of :func:`.integration.integrate` (``method="bdf"``).

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
solve plan's linear solvers, Krylov methods and preconditioners (:mod:`..solve.linear`) serve it
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

Forward sensitivities (``integrate(..., sensitivities=True)``): :math:`S = \\partial
\\Theta/\\partial\\epsilon` solves the variational equations :math:`M\\dot S +
R_\\Theta S + R_\\epsilon = 0`, :math:`S(t_0) = 0`, integrated along by the same steps,
orders and difference form (the staggered direct method, Caracotsios & Stewart 1985; the
``CV_STAGGERED`` option of CVODES): after each accepted step's Newton solve, with the
differences :math:`D^S_j` of :math:`S`,

.. math::

    \\Bigl(\\frac{M}{c} + J(\\Theta_{n+1})\\Bigr) S_{n+1}
        = \\frac{M}{c}\\bigl(S^{(0)} - \\psi^S\\bigr)
        - R_\\epsilon(\\Theta_{n+1}; \\epsilon, t_{n+1}),

one linear solve per parameter with the step's iteration matrix :math:`M/c + J`. The
simplified Newton keeps an older :math:`J`. With a Krylov solver the sensitivities are
solved with the exact operator :math:`M/c + J(\\Theta_{n+1})` (matrix-free, the plan's
preconditioner) to a relative residual ``min(1e-10, rtol/100)``; with a direct solver
the solve is refined with the exact Jacobian at :math:`\\Theta_{n+1}` (matrix-free
products, the iteration matrix as the preconditioner) to the same residual; when a sweep
contracts the residual by less than 10x, or 10 sweeps do not reach it, :math:`M/c +
J(\\Theta_{n+1})` is factorized and that factor preconditions the next steps'
sensitivity solves while :math:`c` is unchanged. So :math:`S_{n+1}` is the step's exact
derivative. The sensitivities are not part of the error test (CVODES' ``errconS =
False``): the steps are those of the state alone, and the sensitivities' accuracy
follows from the state's. Their values at ``t_eval`` come from the same interpolant.
"""

from __future__ import annotations

import numpy as np

from ...errors import KrylovError, ModelEvaluationError
from ..model.operator import GalerkinOperator
from ..model.thresholds import SolveStatus
from ..model.trajectory import Trajectory
from ..solve.plan import NEWTON_ETA_MAX
from .base import Stepper

__all__ = ["VariableBDF"]

MAX_ORDER = 5
NEWTON_MAXITER = 4
MIN_FACTOR, MAX_FACTOR = 0.2, 10.0
# the NDF's kappa (Shampine & Reichelt 1997, Table 1; kappa_5 = 0 makes order 5 a BDF)
KAPPA = np.array([0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415, 0.0])
GAMMA = np.concatenate([[0.0], np.cumsum(1.0 / np.arange(1, MAX_ORDER + 1))])
ALPHA = (1.0 - KAPPA) * GAMMA
ERROR_CONST = KAPPA * GAMMA + 1.0 / np.arange(1, MAX_ORDER + 2)
#: the sensitivity solve's relative residual, its refinement sweeps before refactorizing,
#: and the slowest contraction per sweep worth continuing
SENS_RTOL, SENS_MAXITER, SENS_RATE = 1e-10, 10, 0.1


def _rms(x):
    return float(np.linalg.norm(x) / np.sqrt(x.size))


def _R(order, f):
    i = np.arange(1, order + 1)[:, None]
    j = np.arange(1, order + 1)
    A = np.zeros((order + 1, order + 1))
    A[1:, 1:] = (i - 1 - f * j) / i
    A[0] = 1.0
    return np.cumprod(A, axis=0)


def _difference_change(order, factor):
    """The matrix taking the differences :math:`D_0..D_k` of step size h to those of
    ``factor * h`` (Shampine & Reichelt 1997, Sec. 2.4): ``D <- (R U)^T D``."""
    return (_R(order, factor) @ _R(order, 1.0)).T


class VariableBDF(Stepper):
    """The variable-order (1-5) NDF/BDF with error control (``method="bdf"``, module notes).

    Its step is the backward-Euler-like solve of length :math:`c = h/\\alpha_k` from
    :math:`\\Theta^{(0)} - \\psi` (:meth:`step`); the error estimate
    (:meth:`error_norm`) and the step-size and order choice (:meth:`step_factor`,
    :meth:`next_order`) are Shampine & Reichelt's.
    """

    name = "bdf"
    order = MAX_ORDER
    adaptive = True

    @staticmethod
    def step(h, order, D):
        """``(y_pred, c, psi)`` of a step of size ``h`` and order ``order`` from the
        differences ``D`` (states or sensitivities)."""
        y_pred = D[: order + 1].sum(axis=0)
        psi = np.tensordot(GAMMA[1 : order + 1], D[1 : order + 1], 1) / ALPHA[order]
        return y_pred, h / ALPHA[order], psi

    def error_norm(self, order, d, scale):
        return _rms(ERROR_CONST[order] * d / scale)

    def step_factor(self, order, error_norm, safety):
        return max(MIN_FACTOR, safety * error_norm ** (-1 / (order + 1)))

    @staticmethod
    def next_order(order, D, error_norm, scale, safety):
        """``(order, factor)`` of the next step: of ``order - 1``, ``order``, ``order + 1``
        the one promising the largest step."""
        err_m = _rms(ERROR_CONST[order - 1] * D[order] / scale) if order > 1 else np.inf
        err_p = _rms(ERROR_CONST[order + 1] * D[order + 2] / scale) if order < MAX_ORDER else np.inf
        with np.errstate(divide="ignore"):
            norms = np.array([err_m, error_norm, err_p])
            factors = norms ** (-1.0 / np.arange(order, order + 3))
        order += int(np.argmax(factors)) - 1
        return order, min(MAX_FACTOR, safety * float(np.max(factors)))

    @staticmethod
    def advance(D, order, d):
        """The differences of the new state in place: :math:`D^{j+1}y_n = D^j y_n -
        D^j y_{n-1}`, ``d`` the accepted correction."""
        D[order + 2] = d - D[order + 1]
        D[order + 1] = d
        for i in reversed(range(order + 1)):
            D[i] += D[i + 1]

    @staticmethod
    def interpolate(t, t_new, h, order, D):
        """The step's interpolant :math:`\\Theta_{n+1} + \\sum_{j=1}^k D_j \\prod_{i<j}
        (t - t_{n+1} + i h) / ((i + 1) h)` (Shampine & Reichelt 1997) at the times ``t``
        (m,); returns (m, ...) for ``D`` of shape (k + 3, ...)."""
        i = np.arange(order)
        x = (t[:, None] - (t_new - h * i)) / (h * (1 + i))
        p = np.cumprod(x, axis=1)  # (m, order)
        return D[0] + np.tensordot(p, D[1 : order + 1], 1)


BDF = VariableBDF()


class BDFIntegration:
    """The state of one variable-order BDF integration (module notes), with the forward
    sensitivities when ``sensitivities`` is true."""

    def __init__(self, system, eps, Theta0, t_eval, t0, rtol, atol, first_step, max_step,
                 max_steps, linear, mass_solve, sensitivities=False):  # fmt: skip
        self.system, self.eps, self.t_eval = system, eps, t_eval
        self.rtol, self.atol, self.max_step, self.max_steps = rtol, atol, max_step, max_steps
        self.N, self.P = system.shape
        self.linear, self.mass_solve = linear, mass_solve
        self.newton_tol = max(10 * np.finfo(float).eps / rtol, min(0.03, rtol**0.5))
        self.t, self.y = t0, Theta0.copy()
        self.stats = dict(n_steps=0, n_rejected=0, n_residuals=0, n_jacobians=0, n_factorizations=0)
        if sensitivities:
            self.stats["n_sensitivity_solves"] = 0
        self.first_step = first_step
        self.sensitivities = sensitivities
        self.D = np.zeros((MAX_ORDER + 3, self.N, self.P))
        n = self.N * self.P
        self.DS = np.zeros((MAX_ORDER + 3, n, system.n_eps)) if sensitivities else None
        # (c, factor) of M/c + J at a recent state, for the sensitivity solves
        self.sens_factor = None

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

    def change_step(self, order, factor):
        """Rescale the differences (of the state and the sensitivities) to the step
        ``factor * h``."""
        U = _difference_change(order, factor)
        self.D[: order + 1] = np.tensordot(U, self.D[: order + 1], 1)
        if self.DS is not None:
            self.DS[: order + 1] = np.tensordot(U, self.DS[: order + 1], 1)

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

    def initial_sensitivity_slope(self):
        """:math:`\\dot S(t_0) = -M^{-1}R_\\epsilon(\\Theta_0)` (``Theta0`` does not depend
        on :math:`\\epsilon`), (NP, n_eps)."""
        Re = self.system.eps_jacobian(self.y, self.eps, self.t)
        N, P = self.N, self.P
        cols = [-self.mass_solve(Re[:, j].reshape(N, P)).ravel() for j in range(Re.shape[1])]
        return np.column_stack(cols) if cols else np.zeros((N * P, 0))

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

    # -- sensitivities -------------------------------------------------------------------
    def _mass_columns(self, X):
        """:math:`(M\\otimes\\mathbb E[\\Psi\\Psi^T])X` for ``X`` (NP, m)."""
        N, P = self.N, self.P
        cols = [self.system.apply_mass(X[:, j].reshape(N, P)).ravel() for j in range(X.shape[1])]
        return np.column_stack(cols) if cols else np.zeros_like(X)

    def _solve(self, factor, rhs, rtol=None):
        self.stats["n_sensitivity_solves"] += rhs.shape[1]
        return np.asarray(factor.solve(rhs, rtol=rtol)).reshape(rhs.shape)

    def sensitivity_step(self, t_new, y_new, c, order, factor):
        """Advance the sensitivity differences over the accepted step (module notes);
        ``None``, or the message of a Krylov solve that failed."""
        if self.system.n_eps == 0:
            return None
        system, eps, linear = self.system, self.eps, self.linear
        S_pred, _, psi = BDF.step(0.0, order, self.DS)
        rhs = self._mass_columns(S_pred - psi) / c - system.eps_jacobian(y_new, eps, t_new)
        rel = min(SENS_RTOL, 1e-2 * self.rtol)
        if system.is_linear and not linear.iterative:  # the factor is M/c + J itself
            S = self._solve(factor, rhs)
        elif linear.iterative:  # a Krylov solve with the exact operator at the new state
            A = system.jacobian_operator(y_new, eps, t_new, dt=c)
            if not system.is_linear:  # (a linear system's operator keeps its factor)
                self.stats["n_factorizations"] += 1
            try:
                S = self._solve(linear.factorize(A), rhs, rtol=rel)
            except KrylovError as e:
                return f"the sensitivity solve failed at t={t_new:.6g}: {e}"
        else:
            S = self._refined(factor, rhs, system.jacobian_operator(y_new, eps, t_new, dt=c),
                              c, rel)  # fmt: skip
        BDF.advance(self.DS, order, S - S_pred)
        return None

    def _refined(self, factor, rhs, A, c, rel):
        """:math:`A^{-1}` ``rhs`` by refinement with the direct ``factor`` of an older
        :math:`M/c + J` (or the one kept from an earlier sensitivity solve at this ``c``);
        when a sweep contracts the residual by less than ``1/SENS_RATE``, or
        ``SENS_MAXITER`` sweeps do not reach ``rel``, ``A`` itself is factorized (and kept)."""
        if self.sens_factor is not None and self.sens_factor[0] == c:
            factor = self.sens_factor[1]  # M/c + J at a later state than Newton's
        S = self._solve(factor, rhs)
        bound = rel * np.linalg.norm(rhs, axis=0) + np.finfo(float).tiny
        old = None
        for _ in range(SENS_MAXITER):
            r = rhs - np.column_stack([A.matvec(S[:, j]) for j in range(S.shape[1])])
            norm = np.linalg.norm(r, axis=0)
            if np.all(norm <= bound):
                return S
            if old is not None and np.any(norm > SENS_RATE * old):
                break  # the kept Jacobian is too far from the new one
            S, old = S + self._solve(factor, r), norm
        self.stats["n_factorizations"] += 1
        fresh = self.linear.factorize(A)
        if fresh is None:  # singular at the new state: the refined solve is the best there is
            return S
        self.sens_factor = (c, fresh)
        return self._solve(fresh, rhs)

    # -- the march -----------------------------------------------------------------------
    def run(self):
        system, N, P = self.system, self.N, self.P
        t_eval, D, DS = self.t_eval, self.D, self.DS
        out = np.zeros((len(t_eval), N, P))
        out_S = np.zeros((len(t_eval), N * P, system.n_eps)) if self.sensitivities else None
        n_out = 0
        while n_out < len(t_eval) and t_eval[n_out] == self.t:
            out[n_out] = self.y
            n_out += 1
        t_end = float(t_eval[-1])
        try:
            f0 = -self.mass_solve(self.residual(self.y, self.t))
            fS0 = self.initial_sensitivity_slope() if self.sensitivities else None
        except ModelEvaluationError as e:
            return self.result(out, out_S, n_out, False, f"model evaluation failed at t0: {e}",
                               [], SolveStatus.MODEL_FAILURE)  # fmt: skip
        h = self.first_step if self.first_step is not None else self.initial_step(f0)
        h = min(float(h), self.max_step, t_end - self.t)
        D[0], D[1] = self.y, f0 * h
        if DS is not None:
            DS[1] = fS0 * h
        order, n_equal = 1, 0
        try:
            parts = None if system.is_linear else self.jacobian_parts(self.y, self.t)
        except ModelEvaluationError as e:
            return self.result(out, out_S, n_out, False, f"model evaluation failed at t0: {e}",
                               [], SolveStatus.MODEL_FAILURE)  # fmt: skip
        factor, current_jac = None, True
        nits = []
        while self.t < t_end:
            if self.stats["n_steps"] >= self.max_steps:
                msg = (f"max_steps={self.max_steps} steps reached at t={self.t:.6g} before "
                       f"t_eval[-1]={t_end:g}; raise max_steps or loosen rtol")  # fmt: skip
                return self.result(out, out_S, n_out, False, msg, nits, SolveStatus.MAX_ITERATIONS)
            t = self.t
            min_step = 10 * abs(np.nextafter(t, np.inf) - t)
            if h > self.max_step:
                self.change_step(order, self.max_step / h)
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
                    return self.result(out, out_S, n_out, False, msg, nits, SolveStatus.STEP_SIZE)
                t_new = t + h
                if t_new > t_end:
                    t_new = t_end
                    self.change_step(order, (t_new - t) / h)
                    n_equal, factor = 0, None
                h = t_new - t
                y_pred, c, psi = BDF.step(h, order, D)
                scale = self.scale(y_pred)
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
                    self.change_step(order, 0.5)
                    n_equal, factor = 0, None
                    self.stats["n_rejected"] += 1
                    continue
                safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + nit)
                scale = self.scale(y_new)
                error_norm = BDF.error_norm(order, d, scale)
                if error_norm > 1:
                    f = BDF.step_factor(order, error_norm, safety)
                    h *= f
                    self.change_step(order, f)
                    n_equal = 0
                    self.stats["n_rejected"] += 1
                    # Newton converged: the factorization is kept only if c is unchanged
                    factor = None
                else:
                    accepted = True
            self.stats["n_steps"] += 1
            nits.append(nit)
            n_equal += 1
            if DS is not None:
                failed = self.sensitivity_step(t_new, y_new, c, order, factor)
                if failed is not None:
                    return self.result(out, out_S, n_out, False, f"{system.name}: {failed}",
                                       nits, SolveStatus.KRYLOV_FAILED)  # fmt: skip
            self.t, self.y = t_new, y_new
            current_jac = False
            BDF.advance(D, order, d)
            # dense output on (t, t_new] by the interpolant through the last order+1 states
            k = n_out + int(np.searchsorted(t_eval[n_out:], t_new, side="right"))
            if k > n_out:
                out[n_out:k] = BDF.interpolate(t_eval[n_out:k], t_new, h, order, D)
                if DS is not None:
                    out_S[n_out:k] = BDF.interpolate(t_eval[n_out:k], t_new, h, order, DS)
                n_out = k
            if n_equal < order + 1:
                continue
            order, f = BDF.next_order(order, D, error_norm, scale, safety)
            h *= f
            self.change_step(order, f)
            n_equal, factor = 0, None
        return self.result(out, out_S, n_out, True, "reached t_eval[-1] within the tolerance",
                           nits)  # fmt: skip

    def result(self, out, out_S, n_out, success, message, nits, status=SolveStatus.CONVERGED):
        n = n_out
        N, P = self.N, self.P
        dTheta = None if out_S is None else out_S[:n].reshape(n, N, P, self.system.n_eps)
        return Trajectory(
            self.t_eval[:n].copy(),
            out[:n],
            np.zeros((n, 0)),
            dTheta,
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
