"""Direct factors: objects with ``solve(rhs, rtol=None)`` and ``solve_transpose``.

Dense LU (and a dense Cholesky factor and solve by LAPACK directly), sparse LU, the decoupled block factors of a linear Galerkin system and the
Schur complement of the ECFM bordered system (paper Eq. ecfm_solve).
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from ...errors import SingularSystemError
from .plan import pivots_singular


def dense_lu(J):
    """LU factors of a dense matrix, or ``None`` when it is singular or not finite."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sla.LinAlgWarning)
        lu = sla.lu_factor(J, check_finite=False)
    # lu_factor only warns on exact singularity; detect it ourselves (the plan's threshold)
    d = np.abs(np.diag(lu[0]))
    if pivots_singular(d):
        return None
    return lu


def sparse_lu(A):
    """``splu`` of a sparse matrix, or ``None`` when it is singular or not finite."""
    A = sp.csc_matrix(A)
    if not np.all(np.isfinite(A.data)):
        return None
    try:
        lu = spla.splu(A)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    # like dense_lu: a pivot at round-off of the largest is singular in practice
    d = np.abs(lu.U.diagonal())
    if pivots_singular(d):
        return None
    return lu


class DenseFactor:
    """LU factors of a dense matrix."""

    def __init__(self, lu):
        self.lu = lu

    def solve(self, rhs, rtol=None):
        return _lu_solve(self.lu, rhs, 0)

    def solve_transpose(self, rhs, rtol=None):
        """Solve with the transposed matrix (adjoint equations)."""
        return _lu_solve(self.lu, rhs, 1)


def _lu_solve(lu, rhs, trans):
    """``scipy.linalg.lu_solve(lu, rhs, trans=trans, check_finite=False)``: for float64
    factors and a (n,) or (n, m) float64 right-hand side the same LAPACK ``getrs`` call
    directly (the same bits, without scipy's batching wrapper: ~20 us a call, four
    calls at every point of the random-force ECFM's search); anything else through scipy."""
    b = np.asarray(rhs)
    a, piv = lu
    if (
        b.dtype == np.float64
        and a.dtype == np.float64
        and b.ndim in (1, 2)
        and b.size
        and b.shape[0] == a.shape[0]
    ):
        x, info = lapack.dgetrs(a, piv, b, trans=trans, overwrite_b=0)
        if info == 0:
            return x
    return sla.lu_solve(lu, rhs, trans=trans, check_finite=False)


def cho_factor(S):
    """The upper Cholesky factor of a float64 matrix ``S``: ``scipy.linalg.cho_factor(S)[0]``
    (the same LAPACK ``potrf`` call, so the same bits, and the same errors: ``ValueError``
    for a non-finite ``S``, ``LinAlgError`` where it is not positive definite) without
    scipy's per-call checks and batching wrapper (a few microseconds, several times at
    every point of the random-force ECFM's search)."""
    if not np.isfinite(S).all():
        raise ValueError("array must not contain infs or NaNs")
    c, info = lapack.dpotrf(S, lower=0, overwrite_a=0, clean=0)
    if info > 0:
        raise np.linalg.LinAlgError(
            f"{info}-th leading minor of the array is not positive definite"
        )
    if info < 0:
        raise ValueError(f"LAPACK reported an illegal value in {-info}-th argument of POTRF")
    return c


def cho_solve(c, b):
    """``scipy.linalg.cho_solve((c, False), b)`` for a factor of :func:`cho_factor` (the
    same LAPACK ``potrs`` call: the same bits; ``ValueError`` for a non-finite ``b``)."""
    if not np.isfinite(b).all():
        raise ValueError("array must not contain infs or NaNs")
    x, info = lapack.dpotrs(c, b, lower=0)
    if info != 0:
        raise ValueError(f"illegal value in {-info}th argument of internal potrs")
    return x


class SparseFactor:
    """``splu`` factors of an assembled sparse matrix."""

    def __init__(self, lu):
        self.lu = lu

    def solve(self, rhs, rtol=None):
        return self.lu.solve(np.asarray(rhs, dtype=float))

    def solve_transpose(self, rhs, rtol=None):
        return self.lu.solve(np.asarray(rhs, dtype=float), trans="T")


def _lu_any(A):
    """Factor a dense or sparse square matrix: a DenseFactor/SparseFactor, or ``None``."""
    if sp.issparse(A):
        lu = sparse_lu(A)
        return None if lu is None else SparseFactor(lu)
    lu = dense_lu(A)
    return None if lu is None else DenseFactor(lu)


class BlockFactor:
    """Factors of a decoupled linear Galerkin system (see GalerkinSystem.decoupling).

    Solves :math:`\\sum_q c_q K_q X G_q = B` for ``X`` as ``P`` independent ``N x N``
    solves in the common eigenbasis ``Q`` of the couplings (and the transposed system,
    :math:`\\sum_q c_q K_q^T X G_q = B`, with the same factors).
    """

    def __init__(self, op, Q, D):
        self.Q = Q
        self.N, self.P = op.N, op.P
        self.factors = []
        for p in range(self.P):
            Ap = None
            for part, d in zip(op.parts, D[:, p], strict=True):
                block = (part.coef * d) * part.term.K
                Ap = block if Ap is None else Ap + block
            factor = _lu_any(Ap)
            if factor is None:
                raise np.linalg.LinAlgError(f"decoupled block {p} is singular")
            self.factors.append(factor)

    def _solve(self, rhs, transpose):
        rhs = np.asarray(rhs, dtype=float)
        m = rhs.shape[1] if rhs.ndim == 2 else None
        B = rhs.reshape(self.N, self.P, -1)
        Bh = np.einsum("ikm,kp->ipm", B, self.Q)
        Xh = np.empty_like(Bh)
        for p, factor in enumerate(self.factors):
            solve = factor.solve_transpose if transpose else factor.solve
            Xh[:, p, :] = solve(Bh[:, p, :])
        X = np.einsum("ipm,kp->ikm", Xh, self.Q)
        return X.reshape(self.N * self.P, m) if m is not None else X.reshape(-1)

    def solve(self, rhs, rtol=None):
        return self._solve(rhs, False)

    def solve_transpose(self, rhs, rtol=None):
        return self._solve(rhs, True)


class SchurFactor:
    """Bordered ECFM system solved through the Schur complement on the forces.

    For :math:`\\begin{bmatrix}J & B\\\\ C & 0\\end{bmatrix}
    \\begin{bmatrix}x\\\\ y\\end{bmatrix} = \\begin{bmatrix}a\\\\ b\\end{bmatrix}`:
    :math:`W = J^{-1}B`, :math:`S = C W`, :math:`x_0 = J^{-1}a`,
    :math:`y = S^{-1}(C x_0 - b)`, :math:`x = x_0 - W y`. The transpose is the same
    construction with :math:`(J^T, C^T, B^T)`, built on first use.
    """

    def __init__(self, inner, B, C, rtol, transposed=False):
        self.inner, self.B, self.C, self.rtol = inner, B, C, rtol
        self.transposed = transposed
        self._solve_inner = inner.solve_transpose if transposed else inner.solve
        self.n = B.shape[0]
        self.W = self._solve_inner(np.asarray(B.toarray() if sp.issparse(B) else B), rtol=rtol)
        self.S_lu = dense_lu(np.asarray(C @ self.W))
        self._T = None

    @property
    def singular(self):
        return self.S_lu is None

    def _solve_col(self, rhs, rtol):
        a, b = rhs[: self.n], rhs[self.n :]
        x0 = self._solve_inner(a, rtol=rtol)
        y = sla.lu_solve(self.S_lu, self.C @ x0 - b, check_finite=False)
        return np.concatenate([x0 - self.W @ y, y])

    def solve(self, rhs, rtol=None):
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 1:
            return self._solve_col(rhs, rtol)
        return np.column_stack([self._solve_col(rhs[:, j], rtol) for j in range(rhs.shape[1])])

    def solve_transpose(self, rhs, rtol=None):
        """Solve with the transposed bordered matrix (adjoint of the ECFM step)."""
        if self._T is None:
            if self.transposed:
                raise ValueError("the transpose of a transposed Schur factor is the original")
            self._T = SchurFactor(self.inner, self.C.T, self.B.T, self.rtol, transposed=True)
            if self._T.singular:
                raise SingularSystemError("the transposed ECFM Schur complement is singular")
        return self._T.solve(rhs, rtol)
