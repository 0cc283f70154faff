"""Compiled backward-Euler march and its adjoint for small deterministic systems (private).

The whole step loop of :func:`ecfm_uq.system.march` for ``P = 1`` systems made of dense
linear terms, a quadratic term given by its folded tensor in compressed rows and precomputed loads, with the
optional ECFM data constraint, forward sensitivities and the discrete adjoint, in numba
kernels: no Python work per step or per Newton iteration. The maths is the generic
path's (Eqs. backward_euler, ecfm_solve, discrete_sens, discrete_sens_ecfm); inputs are
prepared and validated by the caller (``solvers._compiled_march``).

Linear algebra: each Newton iteration factorizes the step Jacobian with LAPACK's
``dgetrf`` (the routine ``numpy.linalg.solve`` uses, reached through numba's own LAPACK
binding so the kernels stay cacheable); the triangular solves are short loops here. The
factors at the converged state carry the final Newton correction and the sensitivity
right-hand sides, as in the generic march, and are kept per step for the adjoint, whose
transposed solves then cost two triangular sweeps each. The quadratic term is evaluated
from its folded tensor in compressed rows: ``S = dq/dtheta`` by one sparse pass and
``q = S theta / 2`` (Euler's identity for a form homogeneous of degree 2).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.np.linalg import ensure_lapack

ensure_lapack()  # scipy's LAPACK behind numba's binding (raises if scipy is missing)
# numba's LU binding: info = getrf(kind, m, n, a, lda, ipiv), column-major a, 'd' = 100
_getrf = types.ExternalFunction(
    "numba_xxgetrf",
    types.intc(
        types.char,
        types.intp,
        types.intp,
        types.CPointer(types.float64),
        types.intp,
        types.CPointer(types.int32),
    ),
)
# a pivot below this fraction of the largest is treated as singular (as dense_lu does)
_SINGULAR = 1e-14


@numba.njit(cache=True)
def _lu_factor(A, lu, piv):
    """LU with partial pivoting of the row-major ``A`` (n, n); False when singular.

    ``lu[c, r]`` holds element (r, c) of the factors (LAPACK's column-major layout).
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            lu[j, i] = A[i, j]
    info = _getrf(100, n, n, lu.ctypes, n, piv.ctypes)
    if info != 0:
        return False
    big = 0.0
    small = np.inf
    for i in range(n):
        d = abs(lu[i, i])
        big = max(big, d)
        small = min(small, d)
    return np.isfinite(big) and small > _SINGULAR * big


@numba.njit(cache=True)
def _lu_solve(lu, piv, x):
    """Overwrite ``x`` (n,) with ``A^{-1} x`` from :func:`_lu_factor`'s factors."""
    n = lu.shape[0]
    for i in range(n):
        p = piv[i] - 1
        if p != i:
            x[i], x[p] = x[p], x[i]
    for c in range(n):  # unit lower triangle, column by column
        xc = x[c]
        for r in range(c + 1, n):
            x[r] -= lu[c, r] * xc
    for c in range(n - 1, -1, -1):  # upper triangle
        x[c] /= lu[c, c]
        xc = x[c]
        for r in range(c):
            x[r] -= lu[c, r] * xc


@numba.njit(cache=True)
def _lu_solve_transpose(lu, piv, x):
    """Overwrite ``x`` (n,) with ``A^{-T} x`` (``U^T L^T P^T y = x``)."""
    n = lu.shape[0]
    for r in range(n):  # U^T is lower triangular: U^T[r, c] = lu[r, c], c <= r
        acc = x[r]
        for c in range(r):
            acc -= lu[r, c] * x[c]
        x[r] = acc / lu[r, r]
    for r in range(n - 1, -1, -1):  # L^T, unit upper: L^T[r, c] = lu[r, c], c > r
        acc = x[r]
        for c in range(r + 1, n):
            acc -= lu[r, c] * x[c]
        x[r] = acc
    for i in range(n - 1, -1, -1):
        p = piv[i] - 1
        if p != i:
            x[i], x[p] = x[p], x[i]


@numba.njit(cache=True)
def _quadratic(theta, rows, ptr, idx, val, q, S):
    """S = dq/dth from the folded tensor's compressed rows, and q = S th / 2."""
    S[:, :] = 0.0
    flat = S.reshape(-1)
    for r in range(rows.shape[0]):
        acc = 0.0
        for e in range(ptr[r], ptr[r + 1]):
            acc += val[e] * theta[idx[e]]
        flat[rows[r]] = acc
    q[:] = 0.5 * (S @ theta)


@numba.njit(cache=True)
def march_p1(
    Mdt,
    Klin,
    Ks,
    gK,
    rows,
    ptr,
    idx,
    val,
    cq,
    gq,
    F,
    dF,
    Cobs,
    Gam,
    V,
    theta0,
    guess,
    use_guess,
    tol,
    maxiter,
    sens,
    keep,
):
    """March ``Mdt (th_t - th_{t-1}) + Klin th_t + cq A:th_t th_t - F_t - Gam lam_t = 0``.

    Parameters (shapes)
    -------------------
    Mdt, Klin : (N, N)        mass / dt and sum_q c_q K_q
    Ks : (nq, N, N), gK : (nq, n_eps)   linear operators and their coefficient gradients
    rows, ptr, idx, val       the quadratic term's folded tensor (QuadraticTerm.linearization_table)
    cq : float, gq : (n_eps,) its coefficient and the coefficient's gradient
    F : (n_t, N), dF : (n_t, N, n_eps)  load and its eps-derivative at every time
    Cobs : (C, N), Gam : (N, C), V : (n_t, C)   constraint (C = 0: none)
    theta0 : (N,), guess : (n_t, N + C)  initial state, Newton starts (if use_guess)

    Returns
    -------
    Th (n_t, N), lam (n_t, C), dTh (n_t, N, n_eps), dlam (n_t, C, n_eps), nits (n_t - 1,),
    failed (index of the failed step or -1), rnorm at failure (-1: singular Jacobian),
    LUs, pivs (the converged step Jacobians' factors, kept for the adjoint).
    """
    n_t = F.shape[0]
    N = theta0.shape[0]
    C = Cobs.shape[0]
    n = N + C
    n_eps = gK.shape[1]
    Th = np.zeros((n_t, N))
    Th[0] = theta0
    lam = np.zeros((n_t, C))
    dTh = np.zeros((n_t, N, n_eps))
    dlam = np.zeros((n_t, C, n_eps))
    nits = np.zeros(n_t - 1, dtype=np.int64)
    LUs = np.zeros((n_t - 1 if keep else 0, n, n))
    pivs = np.zeros((n_t - 1 if keep else 0, n), dtype=np.int32)
    q = np.empty(N)
    S = np.empty((N, N))
    J = np.zeros((n, n))
    if C > 0:  # the constraint blocks never change
        J[:N, N:] = -Gam
        J[N:, :N] = Cobs
    r = np.empty(n)
    z = np.empty(n)
    x = np.empty(n)
    lu = np.empty((n, n))
    piv = np.empty(n, dtype=np.int32)
    base = Mdt + Klin
    Kflat = Ks.reshape(Ks.shape[0] * N, N)
    for s in range(n_t - 1):
        t1 = s + 1
        if use_guess:
            z[:] = guess[t1]
        else:
            z[:N] = Th[s]
            z[N:] = lam[s]
        converged = False
        rnorm = np.inf
        rhs = np.empty((N, n_eps))
        for k in range(maxiter + 1):
            th = z[:N]
            _quadratic(th, rows, ptr, idx, val, q, S)
            r[:N] = Mdt @ (th - Th[s]) + Klin @ th + cq * q - F[t1]
            if C > 0:
                r[:N] -= Gam @ z[N:]
                r[N:] = Cobs @ th - V[t1]
            rnorm = np.sqrt(np.sum(r * r))
            if not np.isfinite(rnorm):
                break
            J[:N, :N] = base + cq * S
            nits[s] = k
            if not _lu_factor(J, lu, piv):
                return Th, lam, dTh, dlam, nits, s, -1.0, LUs, pivs
            if rnorm < tol:
                # the last Newton correction is taken with the converged Jacobian, whose
                # factors give the sensitivities (Eqs. discrete_sens / discrete_sens_ecfm)
                converged = True
                if sens:
                    D = -dF[t1] + np.outer(q, gq)
                    if Ks.shape[0] > 0:  # sum_j (K_j th) gK_j^T as one product
                        KTh = (Kflat @ th).reshape(Ks.shape[0], N)
                        D += KTh.T @ gK
                    rhs = Mdt @ dTh[s] - D
            x[:] = r
            _lu_solve(lu, piv, x)
            z -= x
            if converged:
                break
        if not converged:
            return Th, lam, dTh, dlam, nits, s, rnorm, LUs, pivs
        if keep:
            LUs[s] = lu
            pivs[s] = piv
        if sens:
            for j in range(n_eps):
                x[:N] = rhs[:, j]
                x[N:] = 0.0
                _lu_solve(lu, piv, x)
                dTh[t1, :, j] = x[:N]
                dlam[t1, :, j] = x[N:]
        Th[t1] = z[:N]
        lam[t1] = z[N:]
    return Th, lam, dTh, dlam, nits, -1, 0.0, LUs, pivs


@numba.njit(cache=True)
def adjoint_p1(LUs, pivs, Th, Mdt, Ks, gK, rows, ptr, idx, val, gq, dF, g):
    """Discrete adjoint of :func:`march_p1`: the gradient of ``z = sum_t z_t``.

    Backward in time, ``J_t^T mu_t = g_t + [Mdt^T mu_{t+1, theta}; 0]`` and
    ``dz/deps = -sum_t (dR_t/deps)^T mu_{t, theta}`` with
    ``dR_t/deps = sum_j Ks_j th_t gK_j^T + q(th_t) gq^T - dF_t``.

    Parameters (shapes)
    -------------------
    LUs, pivs : (n_t - 1, n, n), (n_t - 1, n)   the march's kept factors (n = N + C)
    Th : (n_t, N)          states
    g : (n_t, n)           dz/d(theta_t, lam_t) (row 0 unused)
    others as in :func:`march_p1`.
    """
    n_t, N = Th.shape
    n = LUs.shape[1]
    n_eps = gK.shape[1]
    grad = np.zeros(n_eps)
    carry = np.zeros(N)
    q = np.empty(N)
    S = np.empty((N, N))
    x = np.empty(n)
    quad_eps = np.any(gq != 0.0)
    # only the linear terms whose coefficients depend on eps: one stacked product each step
    live = np.array([j for j in range(Ks.shape[0]) if np.any(gK[j] != 0.0)], dtype=np.int64)
    Klive = np.ascontiguousarray(Ks[live].reshape(live.shape[0] * N, N))
    glive = np.ascontiguousarray(gK[live])
    for t in range(n_t - 1, 0, -1):
        x[:] = g[t]
        x[:N] += carry
        _lu_solve_transpose(LUs[t - 1], pivs[t - 1], x)
        mu = x[:N]
        th = Th[t]
        grad += dF[t].T @ mu
        if quad_eps:  # skipped when the quadratic coefficient does not depend on eps
            _quadratic(th, rows, ptr, idx, val, q, S)
            grad -= (mu @ q) * gq
        if live.shape[0] > 0:
            KTh = (Klive @ th).reshape(live.shape[0], N)
            grad -= glive.T @ (KTh @ mu)
        carry = Mdt.T @ mu
    return grad
