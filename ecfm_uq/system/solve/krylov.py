"""Matrix-free Krylov solves (CG, GMRES) of the Galerkin Jacobian."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse.linalg as spla

from ...errors import KrylovError
from .plan import ROUNDOFF_FACTOR, UNIT_ROUNDOFF, krylov_accepts


def _pcg(op, b, precond, rtol, maxiter):
    """Preconditioned conjugate gradients on (N, P) arrays with a curvature check.

    Written out (not ``scipy.sparse.linalg.cg``) because CG on an indefinite matrix can
    stall or even converge without notice; here negative curvature ``p'Jp <= 0`` or an
    indefinite preconditioner ``r'z <= 0`` stops the solve with a clear error.
    Returns ``(x, iterations, relative residual)``.
    """
    x = np.zeros_like(b)
    r = b.copy()
    bnorm = np.linalg.norm(b)
    if bnorm == 0.0:
        return x, 0, 0.0
    p = rz_old = None
    for k in range(maxiter + 1):
        res = np.linalg.norm(r) / bnorm
        if res <= rtol:
            return x, k, res
        if k == maxiter:
            break
        z = precond(r)
        rz = np.vdot(r, z)
        if not rz > 0:
            raise ValueError(
                "solver='cg' needs a symmetric positive definite preconditioner "
                f"(r'Mr = {rz:.3g} at iteration {k + 1}): use solver='gmres'"
            )
        p = z if p is None else z + (rz / rz_old) * p
        Ap = op.apply(p)
        curv = np.vdot(p, Ap)
        if not curv > 0:
            raise ValueError(
                "solver='cg' needs a symmetric positive definite Jacobian: negative "
                f"curvature p'Jp = {curv:.3g} at iteration {k + 1}; use solver='gmres'"
            )
        alpha = rz / curv
        x += alpha * p
        r -= alpha * Ap
        rz_old = rz
    return x, maxiter, np.linalg.norm(r) / bnorm


class KrylovFactor:
    """Matrix-free Krylov solves with the mean-based preconditioner.

    ``solve`` raises :class:`KrylovError` when the tolerance is not reached, so a caller
    never sees an unconverged answer.
    """

    def __init__(self, op, method, precond, options, record, transposed=False):
        self.op, self.method, self.precond = op, method, precond
        self.options, self.record = options, record
        self.N, self.P = op.N, op.P
        self.transposed = transposed
        self._T = None

    def _apply_precond(self, R):
        if self.precond is None:
            return R
        return self.precond.apply_transpose(R) if self.transposed else self.precond.apply(R)

    def solve_transpose(self, rhs, rtol=None):
        """Solve with :math:`J^T` (adjoint equations), same preconditioner transposed.

        CG runs only on a symmetric Jacobian with a symmetric preconditioner (the plan's
        rule), so its adjoint solve is the forward solve itself: the same operator and
        preconditioner, no transposed products.
        """
        if self.method == "cg" and not self.transposed:
            return self.solve(rhs, rtol)
        if self._T is None:
            self._T = KrylovFactor(
                self.op.transpose(), self.method, self.precond, self.options, self.record, True
            )
        return self._T.solve(rhs, rtol)

    def _solve_one(self, b, rtol):
        N, P = self.N, self.P
        B = b.reshape(N, P)
        opts = self.options
        if self.method == "cg":
            X, nit, res = _pcg(self.op, B, self._apply_precond, rtol, opts.maxiter)
        else:
            n = N * P
            M = spla.LinearOperator(
                (n, n), matvec=lambda v: self._apply_precond(v.reshape(N, P)).ravel()
            )
            count = [0]

            def callback(_):
                count[0] += 1

            restart = min(opts.restart, n)
            x, _ = spla.gmres(
                self.op.as_linear_operator(),
                b,
                rtol=rtol,
                atol=0.0,
                restart=restart,
                maxiter=math.ceil(opts.maxiter / restart),
                M=M,
                callback=callback,
                callback_type="pr_norm",
            )
            X, nit = x.reshape(N, P), count[0]
            bnorm = np.linalg.norm(b)
            res = np.linalg.norm(B - self.op.apply(X)) / bnorm if bnorm > 0 else 0.0
        self.record.add(nit, res)
        # one rule for every Krylov solve (the plan's): the true residual within 10 rtol,
        # or at the round-off floor of |J||x| (whatever the model's units)
        floor = 0.0
        if not krylov_accepts(res, rtol) and np.isfinite(res):
            bnorm = np.linalg.norm(b)
            if bnorm > 0:
                floor = ROUNDOFF_FACTOR * UNIT_ROUNDOFF * (self.op.magnitude(X) + bnorm) / bnorm
        if not krylov_accepts(res, rtol, floor):
            attainable = f"; floating point can reach about {floor:.1e} here" if floor else ""
            raise KrylovError(
                f"{self.method} did not reach rtol={rtol:.1e}: relative residual {res:.3e} "
                f"after {nit} iterations{attainable} (raise maxiter, or try another "
                "preconditioner)"
            )
        return X.ravel()

    def solve(self, rhs, rtol=None):
        rtol = self.options.rtol if rtol is None else rtol
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 1:
            return self._solve_one(rhs, rtol)
        return np.column_stack([self._solve_one(rhs[:, j], rtol) for j in range(rhs.shape[1])])
