"""Numba kernels behind :mod:`ecfm_uq.chaos` (private; inputs are validated by the callers).

Small kernels, each compiled once and cached on disk (``cache=True``):

``legendre_table``   orthonormal shifted Legendre values by the three-term recurrence
``triple_1d``        the 1-D triple-product table t[i, j, k] = E[L_i L_j L_k] from the
                     Adams-Neumann closed form, only where the selection rules allow
``orthonormal_table``   any germ's orthonormal polynomials from its recurrence coefficients
``hermite_triple_1d``   the Hermite triple-product table in closed form
``recurrence_triple_1d``  any germ's triple-product table from its Jacobi matrix
``triple_dense_mixed``  the multi-variable dense tensor from one table per variable
``triple_sparse_mixed`` the same tensor as coordinate lists, built from the per-variable
                        selection rules (triangle; parity for symmetric germs)
``triple_cross``     the (Pa, P, P) coupling tensor between two bases

A Legendre basis passes its one table once per variable (the same products in the same
order as the v0.2 single-table kernels these replaced, so the tensors are bit-identical).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def legendre_table(x, p):
    """Orthonormal shifted Legendre polynomials L_0..L_p at the points ``x`` in [0, 1].

    Returns ``V`` of shape (n, p + 1) with ``V[q, m] = sqrt(2m + 1) P_m(2 x_q - 1)``, where
    P_m obeys (m + 1) P_{m+1}(t) = (2m + 1) t P_m(t) - m P_{m-1}(t).
    """
    n = x.shape[0]
    V = np.empty((n, p + 1))
    for q in range(n):
        t = 2.0 * x[q] - 1.0
        prev = 1.0
        V[q, 0] = 1.0
        if p >= 1:
            cur = t
            V[q, 1] = np.sqrt(3.0) * t
            for m in range(1, p):
                nxt = ((2.0 * m + 1.0) * t * cur - m * prev) / (m + 1.0)
                prev = cur
                cur = nxt
                V[q, m + 1] = np.sqrt(2.0 * m + 3.0) * nxt
    return V


@numba.njit(cache=True)
def triple_1d(p, normalized):
    """Table t[i, j, k] = E[L_i L_j L_k] for all i, j, k <= p, from the closed form.

    Adams-Neumann: with s = (i + j + k) / 2 and A(n) = prod_{m=1}^{n} (2m - 1) / (2m),

        E[P_i P_j P_k] = A(s - i) A(s - j) A(s - k) / ((2s + 1) A(s))

    when i + j + k is even and |i - j| <= k <= i + j, and exactly 0 otherwise. A(n) is a
    product of numbers in [1/2, 1), so every entry carries only O(p) rounding errors and no
    cancellation. Each unordered triple is computed once and copied to its six
    permutations, so the table is exactly symmetric.
    """
    smax = (3 * p) // 2
    A = np.empty(smax + 1)
    A[0] = 1.0
    for m in range(1, smax + 1):
        A[m] = A[m - 1] * (2.0 * m - 1.0) / (2.0 * m)
    t = np.zeros((p + 1, p + 1, p + 1))
    for i in range(p + 1):
        for j in range(i, p + 1):
            for k in range(j, p + 1):
                if (i + j + k) % 2 == 1 or k > i + j:
                    continue
                s2 = (i + j + k) // 2
                v = A[s2 - i] * A[s2 - j] * A[s2 - k] / ((2.0 * s2 + 1.0) * A[s2])
                if normalized:
                    v *= np.sqrt((2.0 * i + 1.0) * (2.0 * j + 1.0) * (2.0 * k + 1.0))
                t[i, j, k] = v
                t[i, k, j] = v
                t[j, i, k] = v
                t[j, k, i] = v
                t[k, i, j] = v
                t[k, j, i] = v
    return t


@numba.njit(cache=True)
def orthonormal_table(x, p, a, sqrt_b):
    """Orthonormal polynomials psi_0..psi_p of a measure at the points ``x``, shape (n, p + 1).

    From the monic recurrence coefficients (a_m, b_m) of the probability measure:
    sqrt(b_{m+1}) psi_{m+1} = (x - a_m) psi_m - sqrt(b_m) psi_{m-1}, psi_0 = 1.
    """
    n = x.shape[0]
    V = np.empty((n, p + 1))
    for q in range(n):
        t = x[q]
        prev = 0.0
        cur = 1.0
        V[q, 0] = 1.0
        for m in range(p):
            nxt = ((t - a[m]) * cur - sqrt_b[m] * prev) / sqrt_b[m + 1]
            prev = cur
            cur = nxt
            V[q, m + 1] = nxt
    return V


@numba.njit(cache=True)
def hermite_triple_1d(p):
    """Orthonormal Hermite table t[i, j, k] = E[He_i He_j He_k] / sqrt(i! j! k!), exact form.

    With s = (i + j + k) / 2 an integer and |i - j| <= k <= i + j,

        E[He_i He_j He_k] = i! j! k! / ((s - i)! (s - j)! (s - k)!),

    so the orthonormal entry is sqrt(C(i, s - j) C(j, s - i) C(k, s - i)) (the three
    factorial ratios are binomial coefficients because (s - j) + (s - k) = i, etc.). The
    binomials come from Pascal's triangle, exact integers in floating point up to
    C(56, 28); the entry carries at most three roundings.
    """
    C = np.zeros((p + 1, p + 1))
    for n in range(p + 1):
        C[n, 0] = 1.0
        for r in range(1, n + 1):
            C[n, r] = C[n - 1, r - 1] + C[n - 1, r]
    t = np.zeros((p + 1, p + 1, p + 1))
    for i in range(p + 1):
        for j in range(i, p + 1):
            for k in range(j, p + 1):
                if (i + j + k) % 2 == 1 or k > i + j:
                    continue
                s = (i + j + k) // 2
                v = np.sqrt(C[i, s - j] * C[j, s - i] * C[k, s - i])
                t[i, j, k] = v
                t[i, k, j] = v
                t[j, i, k] = v
                t[j, k, i] = v
                t[k, i, j] = v
                t[k, j, i] = v
    return t


@numba.njit(cache=True)
def recurrence_triple_1d(p, a, sqrt_b, parity):
    """t[i, j, k] = E[psi_i psi_j psi_k] for any measure, from its Jacobi matrix (exact algebra).

    With J the (2p + 1) x (2p + 1) Jacobi matrix of the recurrence, psi_j(J) e_k is the
    expansion of psi_j psi_k in the orthonormal basis (exact while j + k <= 2p), so
    E[psi_i psi_j psi_k] = (psi_j(J))_{ik}. The matrices psi_j(J) follow the three-term
    recurrence; only their first p + 1 columns are formed. No quadrature, no moments.
    """
    N = 2 * p + 1
    prev = np.zeros((N, p + 1))
    cur = np.zeros((N, p + 1))
    for k in range(p + 1):
        cur[k, k] = 1.0
    t = np.zeros((p + 1, p + 1, p + 1))
    Ms = np.zeros((p + 1, p + 1, p + 1))  # Ms[j, i, k] = psi_j(J)[i, k]
    for i in range(p + 1):
        for k in range(p + 1):
            Ms[0, i, k] = cur[i, k]
    for j in range(p):
        nxt = np.zeros((N, p + 1))
        for k in range(p + 1):
            for r in range(N):
                # (J cur)[r, k] = sqrt_b[r] cur[r-1] + a[r] cur[r] + sqrt_b[r+1] cur[r+1]
                v = a[r] * cur[r, k]
                if r > 0:
                    v += sqrt_b[r] * cur[r - 1, k]
                if r + 1 < N:
                    v += sqrt_b[r + 1] * cur[r + 1, k]
                nxt[r, k] = (v - a[j] * cur[r, k] - sqrt_b[j] * prev[r, k]) / sqrt_b[j + 1]
        prev = cur
        cur = nxt
        for i in range(p + 1):
            for k in range(p + 1):
                Ms[j + 1, i, k] = cur[i, k]
    for i in range(p + 1):
        for j in range(i, p + 1):
            for k in range(j, p + 1):
                if k > i + j or (parity and (i + j + k) % 2 == 1):
                    continue
                v = Ms[j, i, k]
                t[i, j, k] = v
                t[i, k, j] = v
                t[j, i, k] = v
                t[j, k, i] = v
                t[k, i, j] = v
                t[k, j, i] = v
    return t


@numba.njit(cache=True)
def triple_dense_mixed(alpha, tables):
    """Dense T[a, b, c] = prod_d tables[d][alpha[a, d], alpha[b, d], alpha[c, d]]."""
    P, dim = alpha.shape
    T = np.empty((P, P, P))
    for a in range(P):
        for b in range(P):
            for c in range(P):
                v = 1.0
                for d in range(dim):
                    v *= tables[d, alpha[a, d], alpha[b, d], alpha[c, d]]
                T[a, b, c] = v
    return T


@numba.njit(cache=True)
def _allowed_mixed(alpha, parity, a, b, c):
    # Triangle rule for every germ; the parity rule only for symmetric germs.
    for d in range(alpha.shape[1]):
        i = alpha[a, d]
        j = alpha[b, d]
        k = alpha[c, d]
        if k > i + j or i > j + k or j > i + k:
            return False
        if parity[d] and (i + j + k) % 2 == 1:
            return False
    return True


@numba.njit(cache=True)
def triple_sparse_mixed(alpha, tables, parity):
    """Coordinates and values of the entries the per-germ selection rules allow."""
    P, dim = alpha.shape
    nnz = 0
    for a in range(P):
        for b in range(P):
            for c in range(P):
                if _allowed_mixed(alpha, parity, a, b, c):
                    nnz += 1
    idx = np.empty((nnz, 3), dtype=np.int64)
    val = np.empty(nnz)
    m = 0
    for a in range(P):
        for b in range(P):
            for c in range(P):
                if _allowed_mixed(alpha, parity, a, b, c):
                    v = 1.0
                    for d in range(dim):
                        v *= tables[d, alpha[a, d], alpha[b, d], alpha[c, d]]
                    idx[m, 0] = a
                    idx[m, 1] = b
                    idx[m, 2] = c
                    val[m] = v
                    m += 1
    return idx, val


@numba.njit(cache=True)
def triple_cross(alpha_a, alpha, tables):
    """T[a, i, j] = prod_d tables[d][alpha_a[a, d], alpha[i, d], alpha[j, d]]."""
    Pa, dim = alpha_a.shape
    P = alpha.shape[0]
    T = np.empty((Pa, P, P))
    for a in range(Pa):
        for i in range(P):
            for j in range(P):
                v = 1.0
                for d in range(dim):
                    v *= tables[d, alpha_a[a, d], alpha[i, d], alpha[j, d]]
                T[a, i, j] = v
    return T
