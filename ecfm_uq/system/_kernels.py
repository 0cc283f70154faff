"""Compiled backward-Euler march for small deterministic systems (private).

The whole step loop of :func:`ecfm_uq.system.march` for ``P = 1`` systems made of dense
linear terms, quadratic terms given as coordinate lists and precomputed loads, with the
optional ECFM data constraint and forward sensitivities, in one numba kernel: no Python
work per step or per Newton iteration. The maths is the generic path's (Eqs.
backward_euler, ecfm_solve, discrete_sens, discrete_sens_ecfm); inputs are prepared and
validated by the caller (``solvers._compiled_march``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _quadratic(theta, qi, qj, qk, qv, q, S):
    """q_i = sum A_ijk th_j th_k and S = dq/dth from the coordinate list of A."""
    q[:] = 0.0
    S[:, :] = 0.0
    for e in range(qv.shape[0]):
        i, j, k, v = qi[e], qj[e], qk[e], qv[e]
        q[i] += v * theta[j] * theta[k]
        S[i, j] += v * theta[k]
        S[i, k] += v * theta[j]


@numba.njit(cache=True)
def march_p1(
    Mdt,
    Klin,
    Ks,
    gK,
    qi,
    qj,
    qk,
    qv,
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
    qi, qj, qk, qv : (nnz,)   coordinate list of the summed quadratic tensor A
    cq : float, gq : (n_eps,) its coefficient (1 if it carries the coefficient already)
    F : (n_t, N), dF : (n_t, N, n_eps)  load and its eps-derivative at every time
    Cobs : (C, N), Gam : (N, C), V : (n_t, C)   constraint (C = 0: none)
    theta0 : (N,), guess : (n_t, N + C)  initial state, Newton starts (if use_guess)

    Returns
    -------
    Th (n_t, N), lam (n_t, C), dTh (n_t, N, n_eps), dlam (n_t, C, n_eps), nits (n_t - 1,),
    failed (index of the failed step or -1), rnorm at failure, Js (kept Jacobians).
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
    Js = np.zeros((n_t - 1 if keep else 0, n, n))
    q = np.empty(N)
    S = np.empty((N, N))
    J = np.zeros((n, n))
    r = np.empty(n)
    z = np.empty(n)
    base = Mdt + Klin
    for s in range(n_t - 1):
        t1 = s + 1
        if use_guess:
            z[:] = guess[t1]
        else:
            z[:N] = Th[s]
            z[N:] = lam[s]
        converged = False
        rnorm = np.inf
        for k in range(maxiter + 1):
            th = z[:N]
            _quadratic(th, qi, qj, qk, qv, q, S)
            r[:N] = Mdt @ (th - Th[s]) + Klin @ th + cq * q - F[t1]
            if C > 0:
                r[:N] -= Gam @ z[N:]
                r[N:] = Cobs @ th - V[t1]
            rnorm = np.sqrt(np.sum(r * r))
            if not np.isfinite(rnorm):
                break
            J[:N, :N] = base + cq * S
            if C > 0:
                J[:N, N:] = -Gam
                J[N:, :N] = Cobs
            nits[s] = k
            if rnorm < tol:
                converged = True
                if keep:
                    Js[s] = J
                if sens:
                    # one factorization: the last Newton correction and the sensitivities
                    rhs = np.zeros((n, 1 + n_eps))
                    rhs[:, 0] = r
                    D = -dF[t1] + np.outer(cq * q, gq)
                    for m in range(Ks.shape[0]):
                        D += np.outer(Ks[m] @ th, gK[m])
                    rhs[:N, 1:] = Mdt @ dTh[s] - D
                    X = np.linalg.solve(J, rhs)
                    z -= X[:, 0]
                    dTh[t1] = X[:N, 1:]
                    dlam[t1] = X[N:, 1:]
                else:
                    z -= np.linalg.solve(J, r)
                break
            z -= np.linalg.solve(J, r)
        if not converged:
            return Th, lam, dTh, dlam, nits, s, rnorm, Js
        Th[t1] = z[:N]
        lam[t1] = z[N:]
    return Th, lam, dTh, dlam, nits, -1, 0.0, Js
