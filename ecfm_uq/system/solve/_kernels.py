"""Compiled backward-Euler marches and their adjoint (private; paper Eqs. backward_euler,
ecfm_solve, discrete_sens, discrete_sens_ecfm).

Two numba kernels run the whole step loop of :func:`ecfm_uq.system.march` with no Python
work per step or per Newton iteration; :mod:`.plan` decides when, :mod:`.compiled`
prepares and validates their inputs and translates their status codes (:class:`.plan.SolveStatus`).

:func:`march_p1`
    ``P = 1``: dense linear terms, at most one quadratic term (its folded tensor in
    compressed rows: ``S = dq/dtheta`` in one sparse pass, ``q = S theta / 2``), loads,
    the optional ECFM data constraint, forward sensitivities and the discrete adjoint
    (:func:`adjoint_p1`, two triangular sweeps per step with the kept factors). The step
    Jacobian is factorized by LAPACK's ``dgetrf`` through numba's own binding (so the
    kernels stay cacheable); the converged factors carry the final Newton correction.
:func:`march_sg`
    ``P > 1`` one-germ systems (no data constraint, no kept factors): a chord iteration
    with the node-wise preconditioner (``P`` dense LUs at the germ's Gauss nodes),
    handing over to Newton-Krylov (right-preconditioned GMRES, :func:`_sg_gmres`) when
    it converges slowly; sensitivities are GMRES solves with the same preconditioner.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.np.linalg import ensure_lapack

from ..model.thresholds import (
    KRYLOV_ACCEPT,
    NEWTON_ETA_FACTOR,
    NEWTON_ETA_MAX,
    NEWTON_ETA_MIN,
    ROUNDOFF_FACTOR,
    SINGULAR_PIVOT,
    UNIT_ROUNDOFF,
    SolveStatus,
)

ensure_lapack()  # scipy's LAPACK behind numba's binding (raises if scipy is missing)
# numba's LU binding: info = getrf(kind, m, n, a, lda, ipiv), column-major a, 'd' = 100
_getrf = types.ExternalFunction("numba_xxgetrf", types.intc(
    types.char, types.intp, types.intp, types.CPointer(types.float64), types.intp,
    types.CPointer(types.int32),
))  # fmt: skip
_SINGULAR = SINGULAR_PIVOT  # the plan's thresholds and status codes, frozen in the kernels
_OK = int(SolveStatus.CONVERGED)
_MAX_ITERATIONS = int(SolveStatus.MAX_ITERATIONS)
_SINGULAR_JACOBIAN = int(SolveStatus.SINGULAR_JACOBIAN)
_KRYLOV_FAILED = int(SolveStatus.KRYLOV_FAILED)
_NON_FINITE = int(SolveStatus.NON_FINITE)
_ROUNDOFF = ROUNDOFF_FACTOR * UNIT_ROUNDOFF


@numba.njit(cache=True)
def _lu_factor(A, lu, piv):
    """LU with partial pivoting of the row-major ``A`` (n, n); False when singular.

    ``lu[c, r]`` holds element (r, c) of the factors (LAPACK's column-major layout).
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            lu[j, i] = A[i, j]
    return _lu_factor_inplace(lu, piv)


@numba.njit(cache=True)
def _lu_factor_inplace(lu, piv):
    """LU of the matrix whose element (r, c) is ``lu[c, r]``, in place; False when singular."""
    n = lu.shape[0]
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
def _linearize(Z, rows, ptr, idx, val, Sf):
    """``Sf[i, j P + b] = S(Z[:, b])[i, j]`` for every column of ``Z`` (N, P), one pass.

    ``S(theta) = dq/dtheta`` from the folded tensor's compressed rows
    (``QuadraticTerm.linearization_table``); for ``P = 1``, ``Sf`` is ``S`` itself.
    """
    N, P = Z.shape
    Sf[:, :] = 0.0
    for r in range(rows.shape[0]):
        i = rows[r] // N
        base = (rows[r] - i * N) * P
        for e in range(ptr[r], ptr[r + 1]):
            v = val[e]
            k = idx[e]
            for b in range(P):
                Sf[i, base + b] += v * Z[k, b]


@numba.njit(cache=True)
def _quadratic(theta, rows, ptr, idx, val, q, S):
    """S = dq/dth from the folded tensor's compressed rows, and q = S th / 2."""
    _linearize(theta.reshape(theta.shape[0], 1), rows, ptr, idx, val, S)
    q[:] = 0.5 * (S @ theta)


@numba.njit(cache=True)
def _termination(k, rnorm, scale, tol, tol_s):
    """:func:`.plan.scaled_tol` at a step's first iterate, then :func:`.plan.residual_floor`
    of the step residual's ``scale``: ``(tol_s, floor)``."""
    if k == 0 and scale > 0.0:
        tol_s = tol * min(1.0, scale)
    return tol_s, (_ROUNDOFF * scale if rnorm >= tol_s and _ROUNDOFF * scale > tol_s else 0.0)


@numba.njit(cache=True)
def _p1_scale(th, prev, lam, Mdt, Klin, cq, S, F, Gam, Cobs, V):
    """The magnitude of the ``P = 1`` step residual's terms (:meth:`residual_scale`)."""
    a = np.abs(th)
    scale = np.sqrt(np.sum((np.abs(Mdt) @ (a + np.abs(prev))) ** 2))
    scale += np.sqrt(np.sum((np.abs(Klin) @ a) ** 2))
    scale += 0.5 * abs(cq) * np.sqrt(np.sum((np.abs(S) @ a) ** 2))
    scale += np.sqrt(np.sum(F * F))
    if Cobs.shape[0] > 0:
        scale += np.sqrt(np.sum((np.abs(Gam) @ np.abs(lam)) ** 2))
        scale += np.sqrt(np.sum((np.abs(Cobs) @ a) ** 2)) + np.sqrt(np.sum(V * V))
    return scale


@numba.njit(cache=True)
def march_p1(Mdt, Klin, Ks, gK, rows, ptr, idx, val, cq, gq, F, dF, Cobs, Gam, V, theta0,
        guess, use_guess, tol, maxiter, sens, keep, Mdt2, hsel, wts):  # fmt: skip
    """March ``Mdt (th_t - th_{t-1}) + Klin th_t + cq A:th_t th_t - F_t - Gam lam_t = 0``.

    Two-step schemes (:mod:`.schemes`): step ``s`` uses the mass term ``Mdt2`` where
    ``hsel[s] == 1`` and starts from ``wts[s, 0] th_s + wts[s, 1] th_{s-1}``
    (backward Euler: ``hsel = 0``, ``wts = (1, 0)``, the same arithmetic as before).

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
    failed (index of the failed step or -1), status (a :class:`.plan.SolveStatus` code),
    rnorm at failure, LUs, pivs (the converged step Jacobians' factors, kept for the
    adjoint).
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
    base2 = Mdt2 + Klin
    Kflat = Ks.reshape(Ks.shape[0] * N, N)
    prevb = np.empty(N)
    for s in range(n_t - 1):
        t1 = s + 1
        two = hsel[s] == 1
        Mh = Mdt2 if two else Mdt
        bh = base2 if two else base
        if wts[s, 1] != 0.0:
            prevb[:] = wts[s, 0] * Th[s] + wts[s, 1] * Th[s - 1]
        else:
            prevb[:] = Th[s]
        if use_guess:
            z[:] = guess[t1]
        else:
            z[:N] = Th[s]
            z[N:] = lam[s]
        converged = False
        rnorm = np.inf
        tol_s = tol
        rhs = np.empty((N, n_eps))
        for k in range(maxiter + 1):
            th = z[:N]
            _quadratic(th, rows, ptr, idx, val, q, S)
            r[:N] = Mh @ (th - prevb) + Klin @ th + cq * q - F[t1]
            if C > 0:
                r[:N] -= Gam @ z[N:]
                r[N:] = Cobs @ th - V[t1]
            rnorm = np.sqrt(np.sum(r * r))
            if not np.isfinite(rnorm):
                break
            J[:N, :N] = bh + cq * S
            nits[s] = k
            if not _lu_factor(J, lu, piv):
                return Th, lam, dTh, dlam, nits, s, _SINGULAR_JACOBIAN, rnorm, LUs, pivs
            floor = 0.0
            if k == 0 or rnorm >= tol_s:  # plan.scaled_tol and plan.residual_floor
                sc = _p1_scale(th, prevb, z[N:], Mh, Klin, cq, S, F[t1], Gam, Cobs, V[t1])
                tol_s, floor = _termination(k, rnorm, sc, tol, tol_s)
            if rnorm < tol_s or (floor > 0.0 and rnorm <= floor):
                # the last Newton correction is taken with the converged Jacobian, whose
                # factors give the sensitivities (Eqs. discrete_sens / discrete_sens_ecfm)
                converged = True
                if sens:
                    D = -dF[t1] + np.outer(q, gq)
                    if Ks.shape[0] > 0:  # sum_j (K_j th) gK_j^T as one product
                        KTh = (Kflat @ th).reshape(Ks.shape[0], N)
                        D += KTh.T @ gK
                    if wts[s, 1] != 0.0:
                        rhs = Mh @ (wts[s, 0] * dTh[s] + wts[s, 1] * dTh[s - 1]) - D
                    else:
                        rhs = Mh @ dTh[s] - D
            x[:] = r
            _lu_solve(lu, piv, x)
            z -= x
            if converged:
                break
        if not converged:
            status = _MAX_ITERATIONS if np.isfinite(rnorm) else _NON_FINITE
            return Th, lam, dTh, dlam, nits, s, status, rnorm, LUs, pivs
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
    return Th, lam, dTh, dlam, nits, -1, _OK, 0.0, LUs, pivs


@numba.njit(cache=True)
def adjoint_p1(LUs, pivs, Th, Mdt, Ks, gK, rows, ptr, idx, val, gq, dF, g, Mdt2, hsel, wts):
    """Discrete adjoint of :func:`march_p1`: the gradient of ``z = sum_t z_t``.

    Backward in time, ``J_t^T mu_t = g_t + [Mdt^T mu_{t+1, theta}; 0]`` and
    ``dz/deps = -sum_t (dR_t/deps)^T mu_{t, theta}`` with
    ``dR_t/deps = sum_j Ks_j th_t gK_j^T + q(th_t) gq^T - dF_t``.

    Parameters (shapes)
    -------------------
    LUs, pivs : (n_t - 1, n, n), (n_t - 1, n)   the march's kept factors (n = N + C)
    Th : (n_t, N)          states
    g : (n_t, n)           dz/d(theta_t, lam_t) (row 0 unused)
    others as in :func:`march_p1` (a two-step step carries ``wts[s, j] Mh^T mu`` back to
    the state ``s - j``).
    """
    n_t, N = Th.shape
    n = LUs.shape[1]
    n_eps = gK.shape[1]
    grad = np.zeros(n_eps)
    carry = np.zeros((n_t, N))
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
        x[:N] += carry[t]
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
        c = (Mdt2 if hsel[t - 1] == 1 else Mdt).T @ mu
        carry[t - 1] += wts[t - 1, 0] * c
        if wts[t - 1, 1] != 0.0 and t >= 3:
            carry[t - 2] += wts[t - 1, 1] * c
    return grad


# --------------------------------------------------------------------------------------
# P > 1: the stochastic Galerkin march, preconditioned by the node-wise Jacobians
# --------------------------------------------------------------------------------------
# States are (N, P) chaos coefficients. The quadratic term's linearizations at the P
# chaos columns are kept side by side, Sf[i, j P + b] = S(Theta[:, b])[i, j], so that its
# Galerkin projection sum_{b,c} E[Psi_b Psi_c Psi_l] S_b X_c is one product Sf @ Y(X) with
# Y[j P + b, l] = sum_c X[j, c] E[Psi_b Psi_c Psi_l] (E3m = E3 as (c, b l)).


@numba.njit(cache=True)
def _sg_quadratic(X, Sf, E3m):
    """``sum_{b,c} E[Psi_b Psi_c Psi_l] S_b X[:, c]`` for every l, shape (N, P)."""
    N, P = X.shape
    return Sf @ (X @ E3m).reshape(N * P, P)


@numba.njit(cache=True)
def _sg_mass(X, Mdt, E2, e2_eye, out):
    """``out = Mdt X E2``: the mass term (``E2 = I`` for an orthonormal basis)."""
    if e2_eye:
        out[:, :] = Mdt @ X
    else:
        out[:, :] = (Mdt @ X) @ E2


@numba.njit(cache=True)
def _sg_linear(X, Mdt, E2, e2_eye, Kc, Gs, out):
    """``out = Mdt X E2 + sum_q Kc_q X G_q``: the linear part of the step operator."""
    _sg_mass(X, Mdt, E2, e2_eye, out)
    for j in range(Kc.shape[0]):
        out += (Kc[j] @ X) @ Gs[j]


@numba.njit(cache=True)
def _sg_apply(X, Mdt, E2, e2_eye, Kc, Gs, cq, Sf, E3m, out):
    """``out = J X``, the step Jacobian applied to ``X`` (N, P)."""
    _sg_linear(X, Mdt, E2, e2_eye, Kc, Gs, out)
    if cq != 0.0:
        out += cq * _sg_quadratic(X, Sf, E3m)


@numba.njit(cache=True)
def _sg_factor_nodes(Mdt, Kc, cq, Sf, PhiT, mnode, gnode, LUs, pivs):
    """Factorize the node-wise Jacobians ``mnode_k Mdt + sum_q gnode_qk Kc_q + cq S(u_k)``.

    ``S(u_k) = sum_b PhiT[b, k] S_b`` (S is linear); each matrix is written straight into
    LAPACK's column-major layout. False when one is singular.
    """
    N = Mdt.shape[0]
    P = PhiT.shape[0]
    nq = Kc.shape[0]
    SN = Sf.reshape(N * N, P) @ PhiT if cq != 0.0 else np.zeros((N * N, P))
    for kn in range(P):
        lu = LUs[kn]
        m = mnode[kn]
        for i in range(N):
            for j in range(N):
                a = m * Mdt[i, j] + cq * SN[i * N + j, kn]
                for q in range(nq):
                    a += gnode[q, kn] * Kc[q, i, j]
                lu[j, i] = a
        if not _lu_factor_inplace(lu, pivs[kn]):
            return False
    return True


@numba.njit(cache=True)
def _sg_precond(R, Tn, Tb, LUs, pivs, out):
    """``out`` = the node-wise preconditioner applied to ``R`` (N, P).

    Chaos columns to node values (``R Tn``), one LU solve per node, back (``X Tb``).
    """
    Rn = R @ Tn
    x = np.empty(R.shape[0])
    for k in range(Rn.shape[1]):
        x[:] = Rn[:, k]
        _lu_solve(LUs[k], pivs[k], x)
        Rn[:, k] = x
    out[:, :] = Rn @ Tb


@numba.njit(cache=True)
def _sg_scale(Z, prev, Mdt, E2, Kc, Gs, cq, rows, ptr, idx, val, E3m, F):
    """The magnitude of the ``P > 1`` step residual's terms (:meth:`residual_scale`)."""
    N, P = Z.shape
    A = np.abs(Z)
    scale = np.sqrt(np.sum(((np.abs(Mdt) @ (A + np.abs(prev))) @ np.abs(E2)) ** 2))
    for j in range(Kc.shape[0]):
        scale += np.sqrt(np.sum(((np.abs(Kc[j]) @ A) @ np.abs(Gs[j])) ** 2))
    if rows.shape[0] > 0 and cq != 0.0:
        Sa = np.zeros((N, N * P))
        _linearize(A, rows, ptr, idx, np.abs(val), Sa)
        scale += 0.5 * abs(cq) * np.sqrt(np.sum(_sg_quadratic(A, Sa, np.abs(E3m)) ** 2))
    scale += np.sqrt(np.sum(F * F))
    return scale


@numba.njit(cache=True)
def _sg_gmres(
    b, Mdt, E2, e2_eye, Kc, Gs, cq, Sf, E3m, Tn, Tb, LUs, pivs, rtol, restart, maxiter, x
):
    """Right-preconditioned restarted GMRES for ``J x = b`` (``b``, ``x`` of shape (N, P)).

    Returns ``(iterations, relative residual)``; ``x`` is overwritten (zero start).
    Right preconditioning keeps the monitored residual the true one; the restart's
    residual is recomputed, so the returned value is not an estimate.
    """
    N, P = b.shape
    n = N * P
    x[:, :] = 0.0
    bnorm = np.sqrt(np.sum(b * b))
    if bnorm == 0.0:
        return 0, 0.0
    m = restart
    V = np.empty((m + 1, n))
    Zs = np.empty((m, n))
    H = np.zeros((m + 1, m))
    cs = np.empty(m)
    sn = np.empty(m)
    g = np.empty(m + 1)
    r = b.copy()
    w = np.empty((N, P))
    z = np.empty((N, P))
    its = 0
    while True:
        rel = np.sqrt(np.sum(r * r)) / bnorm
        if rel <= rtol or its >= maxiter:
            return its, rel
        V[0] = r.reshape(n) / (rel * bnorm)
        g[:] = 0.0
        g[0] = rel * bnorm
        H[:, :] = 0.0
        j_end = 0
        for j in range(m):
            _sg_precond(V[j].reshape(N, P), Tn, Tb, LUs, pivs, z)
            Zs[j] = z.reshape(n)
            _sg_apply(z, Mdt, E2, e2_eye, Kc, Gs, cq, Sf, E3m, w)
            wv = w.reshape(n).copy()
            for i in range(j + 1):  # modified Gram-Schmidt
                h = np.dot(V[i], wv)
                H[i, j] = h
                wv -= h * V[i]
            hn = np.sqrt(np.dot(wv, wv))
            H[j + 1, j] = hn
            for i in range(j):  # the previous Givens rotations
                t = cs[i] * H[i, j] + sn[i] * H[i + 1, j]
                H[i + 1, j] = -sn[i] * H[i, j] + cs[i] * H[i + 1, j]
                H[i, j] = t
            d = np.sqrt(H[j, j] ** 2 + H[j + 1, j] ** 2)
            if d == 0.0:
                return its, np.inf
            cs[j] = H[j, j] / d
            sn[j] = H[j + 1, j] / d
            H[j, j] = d
            H[j + 1, j] = 0.0
            g[j + 1] = -sn[j] * g[j]
            g[j] = cs[j] * g[j]
            its += 1
            j_end = j + 1
            if abs(g[j + 1]) <= rtol * bnorm or hn == 0.0 or its >= maxiter:
                break
            V[j + 1] = wv / hn
        y = np.zeros(j_end)  # back substitution on the rotated Hessenberg matrix
        for i in range(j_end - 1, -1, -1):
            acc = g[i]
            for k in range(i + 1, j_end):
                acc -= H[i, k] * y[k]
            y[i] = acc / H[i, i]
        xf = x.reshape(n)
        for i in range(j_end):
            xf += y[i] * Zs[i]
        _sg_apply(x, Mdt, E2, e2_eye, Kc, Gs, cq, Sf, E3m, w)
        r = b - w


@numba.njit(cache=True)
def march_sg(Mdt, E2, Ks, cs, Gs, gK, rows, ptr, idx, val, cq, gq, E3m, F, dF, PhiT, Tn, Tb,
        mnode, gnode, theta0, guess, use_guess, tol, maxiter, sens, sens_rtol, restart,
        lin_maxiter, chord_rate, Mdt2, hsel, wts):  # fmt: skip
    """March the ``P > 1`` Galerkin system (no data constraint), preconditioned node-wise.

    Two-step schemes as in :func:`march_p1` (``Mdt2``, ``hsel``, ``wts``).

    Step residual (Eq. backward_euler projected on the chaos basis)
    ``R = Mdt (Z - Th_{t-1}) E2 + sum_q c_q K_q Z G_q + cq/2 sum_{b,c} E3[b,c,:] S_b Z_c - F_t``.
    The preconditioner ``B`` is the Galerkin Jacobian with the triple products taken by
    the germ's ``P``-node Gauss rule: in node values it splits into the deterministic
    Jacobians ``mnode_k Mdt + sum_q gnode_qk c_q K_q + cq S(u_k)`` at the nodes, the
    matrices a collocation solve factorizes. Each step first iterates
    ``Z <- Z - B^{-1} R(Z)`` with ``B`` factorized once at the step's first iterate (a
    chord iteration: ``B`` differs from the Jacobian by the quadrature's aliasing, a few
    per cent for a smooth random input); if the residual falls by less than a factor
    ``chord_rate`` per iteration the rest of the step is Newton-Krylov (GMRES
    preconditioned by ``B`` refreshed every Newton step, linear tolerance
    the plan's forcing term, :func:`.plan.newton_rtol`). Sensitivities (Eq. discrete_sens)
    are GMRES solves to ``sens_rtol``; every GMRES answer is accepted by the plan's rule
    (true relative residual within ``KRYLOV_ACCEPT * rtol``). ``chord_rate <= 0``:
    Newton-Krylov from the first iteration.

    Parameters (shapes)
    -------------------
    Mdt (N, N), E2 (P, P)          mass / dt and its coupling E[Psi Psi^T]
    Ks (nq, N, N), cs (nq,)        linear operators and their coefficients
    Gs (nq, P, P), gK (nq, n_eps)  their couplings and coefficient gradients
    rows, ptr, idx, val            the quadratic term's folded tensor (empty: none)
    cq, gq (n_eps,)                its coefficient and gradient
    E3m (P, P * P)                 E3[b, c, l] as row c, column b P + l
    F (n_t, N, P), dF (n_t, N, P, n_eps)   loads (chaos coefficients) and derivatives
    PhiT (P, P)                    PhiT[b, k] = Psi_b(node_k)
    Tn, Tb (P, P)                  residual chaos columns to node values; node values back
    mnode (P,), gnode (nq, P)      node factors of the mass coupling and of each G_q
    theta0 (N, P), guess (n_t, N, P)

    Returns
    -------
    Th (n_t, N, P), dTh (n_t, N, P, n_eps), nits (n_t - 1,) iterations per step,
    kits (n_t - 1,) GMRES iterations per step (sensitivities included), failed step
    (-1: none), status (a :class:`.plan.SolveStatus` code), rnorm at failure.
    """
    n_t = F.shape[0]
    N, P = theta0.shape
    nq = Ks.shape[0]
    n_eps = gK.shape[1]
    e2_eye = True
    for a in range(P):
        for b in range(P):
            if E2[a, b] != (1.0 if a == b else 0.0):
                e2_eye = False
    Kc = np.empty_like(Ks)
    for j in range(nq):
        Kc[j] = cs[j] * Ks[j]
    has_quad = rows.shape[0] > 0 and cq != 0.0
    cq_eff = cq if has_quad else 0.0
    Th = np.zeros((n_t, N, P))
    Th[0] = theta0
    dTh = np.zeros((n_t, N, P, n_eps))
    nits = np.zeros(n_t - 1, dtype=np.int64)
    kits = np.zeros(n_t - 1, dtype=np.int64)
    Sf = np.zeros((N, N * P))
    LUs = np.empty((P, N, N))
    pivs = np.empty((P, N), dtype=np.int32)
    R = np.empty((N, P))
    X = np.empty((N, P))
    for s in range(n_t - 1):
        t1 = s + 1
        Z = guess[t1].copy() if use_guess else Th[s].copy()
        converged = False
        factored = False
        krylov = False
        rnorm = np.inf
        prev = np.inf
        two = hsel[s] == 1
        Mh = Mdt2 if two else Mdt
        if wts[s, 1] != 0.0:
            Pv = wts[s, 0] * Th[s] + wts[s, 1] * Th[s - 1]
        else:
            Pv = Th[s].copy()
        _sg_mass(Pv, Mh, E2, e2_eye, X)
        Fs = F[t1] + X  # the step's fixed part: load and previous state
        tol_s = tol
        for k in range(maxiter + 1):
            if has_quad:
                _linearize(Z, rows, ptr, idx, val, Sf)
            _sg_linear(Z, Mh, E2, e2_eye, Kc, Gs, R)
            if has_quad:
                R += (0.5 * cq) * _sg_quadratic(Z, Sf, E3m)
            R -= Fs
            rnorm = np.sqrt(np.sum(R * R))
            nits[s] = k
            if not np.isfinite(rnorm):
                break
            floor = 0.0
            if k == 0 or rnorm >= tol_s:  # plan.scaled_tol and plan.residual_floor
                sc = _sg_scale(Z, Pv, Mh, E2, Kc, Gs, cq_eff, rows, ptr, idx, val, E3m,
                               F[t1])  # fmt: skip
                tol_s, floor = _termination(k, rnorm, sc, tol, tol_s)
            if rnorm < tol_s or (floor > 0.0 and rnorm <= floor):
                converged = True
                break
            if k == maxiter:
                break
            if not krylov and (chord_rate <= 0.0 or (k > 0 and rnorm > chord_rate * prev)):
                krylov = True
            if krylov or not factored:
                if not _sg_factor_nodes(Mh, Kc, cq_eff, Sf, PhiT, mnode, gnode, LUs, pivs):
                    return Th, dTh, nits, kits, s, _SINGULAR_JACOBIAN, rnorm
                factored = True
            if krylov:
                eta = max(NEWTON_ETA_FACTOR * tol_s / rnorm, NEWTON_ETA_MIN, floor / rnorm)
                eta = min(NEWTON_ETA_MAX, eta)
                its, rel = _sg_gmres(
                    R, Mh, E2, e2_eye, Kc, Gs, cq_eff, Sf, E3m, Tn, Tb, LUs, pivs, eta,
                    restart, lin_maxiter, X,
                )  # fmt: skip
                kits[s] += its
                if not rel <= KRYLOV_ACCEPT * eta:
                    return Th, dTh, nits, kits, s, _KRYLOV_FAILED, rnorm
            else:
                _sg_precond(R, Tn, Tb, LUs, pivs, X)
            Z -= X
            prev = rnorm
        if not converged:
            status = _MAX_ITERATIONS if np.isfinite(rnorm) else _NON_FINITE
            return Th, dTh, nits, kits, s, status, rnorm
        Th[t1] = Z
        if not sens:
            continue
        # dTh_t solves J dTh_t = Mdt dTh_{t-1} E2 - dR/deps (Eq. discrete_sens), J at the
        # converged state (Sf is), preconditioned by this step's node factors
        if not factored:
            if not _sg_factor_nodes(Mh, Kc, cq_eff, Sf, PhiT, mnode, gnode, LUs, pivs):
                return Th, dTh, nits, kits, s, _SINGULAR_JACOBIAN, rnorm
        Wq = 0.5 * _sg_quadratic(Z, Sf, E3m) if has_quad else np.zeros((N, P))
        rhs = np.empty((N, P))
        for e in range(n_eps):
            if wts[s, 1] != 0.0:
                dP = wts[s, 0] * dTh[s, :, :, e] + wts[s, 1] * dTh[s - 1, :, :, e]
            else:
                dP = np.ascontiguousarray(dTh[s, :, :, e])
            _sg_mass(dP, Mh, E2, e2_eye, rhs)
            rhs += dF[t1, :, :, e]
            for j in range(nq):
                if gK[j, e] != 0.0:
                    rhs -= gK[j, e] * ((Ks[j] @ Z) @ Gs[j])
            if has_quad and gq[e] != 0.0:
                rhs -= gq[e] * Wq
            its, rel = _sg_gmres(
                rhs, Mh, E2, e2_eye, Kc, Gs, cq_eff, Sf, E3m, Tn, Tb, LUs, pivs, sens_rtol,
                restart, lin_maxiter, X,
            )  # fmt: skip
            kits[s] += its
            if not rel <= KRYLOV_ACCEPT * sens_rtol:
                return Th, dTh, nits, kits, s, _KRYLOV_FAILED, rnorm
            dTh[t1, :, :, e] = X
    return Th, dTh, nits, kits, -1, _OK, 0.0
