"""Numba kernels behind :mod:`ecfm_uq.chaos` (private; inputs are validated by the callers).

Four small kernels, each compiled once and cached on disk (``cache=True``):

``legendre_table``   orthonormal shifted Legendre values by the three-term recurrence
``triple_1d``        the 1-D triple-product table t[i, j, k] = E[L_i L_j L_k] from the
                     Adams-Neumann closed form, only where the selection rules allow
``triple_dense``     the multi-variable dense tensor from the per-variable factors
``triple_sparse``    the same tensor as coordinate lists, built from the selection rules
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
def triple_dense(alpha, t):
    """Dense T[a, b, c] = prod_d t[alpha[a, d], alpha[b, d], alpha[c, d]], shape (P, P, P)."""
    P, dim = alpha.shape
    T = np.empty((P, P, P))
    for a in range(P):
        for b in range(P):
            for c in range(P):
                v = 1.0
                for d in range(dim):
                    v *= t[alpha[a, d], alpha[b, d], alpha[c, d]]
                T[a, b, c] = v
    return T


@numba.njit(cache=True)
def _allowed(alpha, a, b, c):
    # Selection rules per variable: parity and the triangle inequality.
    for d in range(alpha.shape[1]):
        i = alpha[a, d]
        j = alpha[b, d]
        k = alpha[c, d]
        if (i + j + k) % 2 == 1 or k > i + j or i > j + k or j > i + k:
            return False
    return True


@numba.njit(cache=True)
def triple_sparse(alpha, t):
    """Coordinates (nnz, 3) and values (nnz,) of the structurally nonzero entries.

    Two passes over (a, b, c): count, then fill, so memory is exactly nnz.
    """
    P, dim = alpha.shape
    nnz = 0
    for a in range(P):
        for b in range(P):
            for c in range(P):
                if _allowed(alpha, a, b, c):
                    nnz += 1
    idx = np.empty((nnz, 3), dtype=np.int64)
    val = np.empty(nnz)
    m = 0
    for a in range(P):
        for b in range(P):
            for c in range(P):
                if _allowed(alpha, a, b, c):
                    v = 1.0
                    for d in range(dim):
                        v *= t[alpha[a, d], alpha[b, d], alpha[c, d]]
                    idx[m, 0] = a
                    idx[m, 1] = b
                    idx[m, 2] = c
                    val[m] = v
                    m += 1
    return idx, val
