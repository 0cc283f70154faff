"""The Jacobian of the stochastic Galerkin system as a structured operator.

Linearizing :math:`R(\\Theta; \\epsilon, \\lambda)` (paper Eq. pce) at :math:`\\Theta` gives,
in the row-major :math:`\\mathrm{vec}(\\Theta)` (flat index ``i * P + k``),

.. math::

    J = \\sum_q c_q(\\epsilon)\\, K_q \\otimes G_q^T
        + \\sum_{\\text{quadratic}} c(\\epsilon) \\sum_k S_k \\otimes \\mathbb E[\\Psi\\Psi\\Psi_k]
        \\;\\bigl(+\\tfrac{1}{\\Delta t} M \\otimes \\mathbb E[\\Psi\\Psi^T]\\bigr),

a sum of Kronecker products, as in Trilinos Stokhos and the solvers of Powell & Elman
(2009). :class:`GalerkinOperator` holds that structure and offers it in every form a
solver needs: the matrix-free product (cost :math:`O(\\sum_q \\mathrm{nnz}(K_q) P +
N\\,\\mathrm{nnz}(G_q))`), the dense or sparse assembled matrix, and the mean block
:math:`\\sum_q c_q\\,\\mathbb E[g_q] K_q` used by the mean-based preconditioner. Which
form is used is decided in one place, :mod:`..solve.linear`.

:class:`AugmentedOperator` adds the ECFM data constraint (Eq. ecfm_solve): unknowns
:math:`(\\Theta, \\lambda)` with the bordered matrix
:math:`\\begin{bmatrix} J & -\\Gamma\\otimes\\mathbb E[\\Psi] \\\\ \\mathcal M\\otimes
\\mathbb E[\\Psi]^T & 0\\end{bmatrix}`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ...memory import check_allocation

__all__ = ["AugmentedOperator", "GalerkinOperator"]


class _LinearPart:
    """:math:`c\\,K\\otimes G^T` of one linear term at fixed :math:`\\epsilon`."""

    is_quadratic = False

    def __init__(self, term, coef):
        self.term, self.coef = term, coef

    def apply(self, X):
        return self.coef * self.term.action(X)

    def apply_transpose(self, Y):
        return self.coef * self.term.action_transpose(Y)

    def dense(self):
        return self.coef * self.term.kron("dense")

    def sparse(self):
        return self.coef * self.term.kron("sparse")

    def mean_block(self, E2_00):
        return (self.coef * self.term.G[0, 0] / E2_00) * self.term.K

    def kronecker_terms(self):
        """``[(K, C)]`` with :meth:`apply` ``= sum K X C`` (the Kronecker preconditioner)."""
        return [(self.term.K, self.coef * self.term.G)]

    def magnitude(self, X):
        return abs(self.coef) * self.term.magnitude(X)


class _QuadraticLinearization:
    """The Jacobian of one quadratic term at a fixed state."""

    is_quadratic = True

    def __init__(self, term, Theta, coef):
        self.term, self.Theta, self.coef = term, Theta, coef

    def apply(self, X):
        return self.coef * self.term.linear_action(self.Theta, X)

    def magnitude(self, X):
        return abs(self.coef) * self.term.magnitude(self.Theta, X)

    def apply_transpose(self, Y):
        # (J^T Y)[j, b] = sum_k sum_a E3[a, b, k] (S_k^T Y)[j, a]
        E3 = self.term.E3
        out = np.zeros_like(Y)
        for k, Sk in enumerate(self.term.matrices(self.Theta)):
            Ek = E3[:, :, k]
            if np.any(Ek):
                out += (Sk.T @ Y) @ Ek
        return self.coef * out

    def dense(self):
        N, P = self.Theta.shape
        S = self.term.matrices(self.Theta)
        if P == 1:
            return self.coef * S[0]
        S = np.stack(S)  # (P, N, N)
        E3 = self.term.E3
        # J[i, a, j, b] = sum_k E3[a, b, k] S_k[i, j], as one matrix product
        T = (E3.reshape(P * P, P) @ S.reshape(P, N * N)).reshape(P, P, N, N)
        return self.coef * T.transpose(2, 0, 3, 1).reshape(N * P, N * P)

    def sparse(self):
        E3 = self.term.E3
        out = None
        for k, Sk in enumerate(self.term.matrices(self.Theta)):
            Ek = E3[:, :, k]
            if not np.any(Ek):
                continue
            block = sp.kron(sp.csr_matrix(Sk), sp.csr_matrix(Ek), format="csr")
            out = block if out is None else out + block
        return self.coef * out

    def kronecker_terms(self):
        """``[(S_k, E_k^T)]``: :meth:`apply` ``= sum_k S_k X E_k^T``."""
        E3 = self.term.E3
        return [
            (self.coef * Sk, E3[:, :, k].T)
            for k, Sk in enumerate(self.term.matrices(self.Theta))
            if np.any(E3[:, :, k])
        ]

    def mean_block(self, E2_00):
        """The (0, 0) chaos block divided by :math:`\\mathbb E[\\Psi_0^2]`."""
        E3 = self.term.E3
        S = None
        for k in np.nonzero(E3[0, 0, :])[0]:
            Sk = E3[0, 0, k] * self.term.form.matrix(self.Theta[:, k])
            S = Sk if S is None else S + Sk
        return self.coef * S / E2_00


class GalerkinOperator:
    """:math:`J = \\partial\\,\\mathrm{vec}R/\\partial\\,\\mathrm{vec}\\Theta` in structured form.

    Built by :meth:`GalerkinSystem.jacobian_operator`; not usually constructed by hand.

    Parameters
    ----------
    system : GalerkinSystem
    parts : list
        One linearized part per state-dependent term, in the system's term order.
    dt : float, optional
        Adds :math:`M \\otimes \\mathbb E[\\Psi\\Psi^T] / \\Delta t` (a backward-Euler step).
    """

    def __init__(self, system, parts, dt=None):
        self.system = system
        self.N, self.P = system.shape
        self.parts = list(parts)
        self.dt = dt
        self.shape = (self.N * self.P, self.N * self.P)

    # -- properties ------------------------------------------------------------------
    @property
    def size(self):
        """Number of unknowns NP."""
        return self.shape[0]

    @property
    def is_linear(self):
        """No quadratic term: the operator does not depend on the state."""
        return not any(part.is_quadratic for part in self.parts)

    # -- action ----------------------------------------------------------------------
    def apply(self, X):
        """:math:`J\\,\\mathrm{vec}(X)` reshaped: ``X`` (N, P) -> (N, P), matrix-free."""
        X = np.ascontiguousarray(X)  # else every sparse product copies it
        Y = np.zeros((self.N, self.P))
        for part in self.parts:
            Y += part.apply(X)
        if self.dt is not None:
            Y += self.system.apply_mass(X) / self.dt
        return Y

    def magnitude(self, X):
        """:math:`\\| |J|\\,|\\mathrm{vec}X| \\|` (a float): the round-off scale of :meth:`apply`
        at ``X`` (N, P), against which a Krylov answer's residual is judged
        (:func:`..solve.plan.krylov_accepts`)."""
        Y = np.zeros((self.N, self.P))
        for part in self.parts:
            Y += part.magnitude(X)
        s = float(np.linalg.norm(Y))
        if self.dt is not None:
            s += self.system.mass_scale(X) / self.dt
        return s

    def apply_transpose(self, Y):
        """:math:`J^T\\,\\mathrm{vec}(Y)` reshaped (the adjoint action), matrix-free."""
        X = np.zeros((self.N, self.P))
        for part in self.parts:
            X += part.apply_transpose(Y)
        if self.dt is not None:
            X += self.system.apply_mass(Y, transpose=True) / self.dt
        return X

    def matvec(self, x):
        """:math:`J x` for a flat ``x`` of length NP."""
        return self.apply(np.reshape(x, (self.N, self.P))).ravel()

    def rmatvec(self, y):
        """:math:`J^T y` for a flat ``y`` of length NP."""
        return self.apply_transpose(np.reshape(y, (self.N, self.P))).ravel()

    def as_linear_operator(self):
        """A ``scipy.sparse.linalg.LinearOperator`` applying :math:`J` matrix-free."""
        return spla.LinearOperator(
            self.shape, matvec=self.matvec, rmatvec=self.rmatvec, dtype=float
        )

    def transpose(self):
        """:math:`J^T` as an object with ``apply``/``size`` (for adjoint Krylov solves)."""
        return _Transposed(self)

    # -- assembly --------------------------------------------------------------------
    def dense_nbytes(self):
        """Bytes of the dense matrix."""
        return 8.0 * self.size**2

    def to_dense(self):
        """The assembled ``(NP, NP)`` matrix (checked against the memory budget first)."""
        n = self.size
        check_allocation(
            self.dense_nbytes(),
            f"the dense Jacobian of {self.system.name!r} (NP = {n})",
            "pass solver='cg' or 'gmres' (matrix-free) or 'sparse-direct'",
        )
        J = np.zeros((n, n))
        for part in self.parts:
            J += part.dense()
        if self.dt is not None:
            J = self.system.structure.mass_over_dt(self.dt) + J
        return J

    def to_sparse(self):
        """The assembled matrix as CSR (no dense array of size N^2 or (NP)^2)."""
        J = sp.csr_matrix(self.shape)
        for part in self.parts:
            J = J + part.sparse()
        if self.dt is not None:
            J = J + self.system.mass_matrix(sparse=True) / self.dt
        return J.tocsr()

    def mean_block(self):
        """:math:`\\bar K`, the (0, 0) chaos block over :math:`\\mathbb E[\\Psi_0^2]`, (N, N).

        For an orthonormal basis this is the Jacobian of the mean problem,
        :math:`\\sum_q c_q\\,\\mathbb E[g_q] K_q` (+ the quadratic terms linearized at the
        mean state, + :math:`M/\\Delta t`). Sparse when any operator is sparse.
        """
        E2 = self.system.E2
        e00 = E2[0, 0]
        blocks = [part.mean_block(e00) for part in self.parts]
        if self.dt is not None:
            blocks.append(self.system.M / self.dt)
        K = None
        for block in blocks:
            if K is not None and sp.issparse(K) != sp.issparse(block):
                K, block = sp.csr_matrix(K), sp.csr_matrix(block)
            K = block if K is None else K + block
        if K is None:
            raise ValueError(f"system {self.system.name!r} has no operator acting on Theta")
        return K.tocsc() if sp.issparse(K) else K


class _Transposed:
    """View of a GalerkinOperator as its transpose (apply = the adjoint action)."""

    def __init__(self, op):
        self.op, self.N, self.P, self.shape = op, op.N, op.P, op.shape

    def apply(self, Y):
        return self.op.apply_transpose(Y)

    def magnitude(self, Y):
        # |J^T| |y| is estimated by |J| |y|: the same entries, the scale is what matters
        return self.op.magnitude(Y)

    def matvec(self, y):
        return self.op.rmatvec(y)

    def as_linear_operator(self):
        return spla.LinearOperator(self.shape, matvec=self.matvec, dtype=float)


class AugmentedOperator:
    """The ECFM bordered Jacobian for the unknowns :math:`(\\mathrm{vec}\\Theta, \\lambda)`.

    Parameters
    ----------
    J : GalerkinOperator
    Jl : (NP, C) ndarray
        :math:`\\partial R/\\partial\\lambda = -\\Gamma\\otimes\\mathbb E[\\Psi]`.
    Cth : (C, NP) ndarray or sparse
        :math:`\\mathcal M\\otimes\\mathbb E[\\Psi]^T`, the constraint's Jacobian.
    """

    def __init__(self, J, Jl, Cth):
        self.J, self.Jl, self.Cth = J, Jl, Cth
        self.n_forces = Jl.shape[1]
        n = J.size + self.n_forces
        self.shape = (n, n)
        self.is_linear = J.is_linear

    @property
    def size(self):
        return self.shape[0]

    def dense_nbytes(self):
        return 8.0 * self.size**2

    def to_dense(self):
        check_allocation(
            self.dense_nbytes(),
            f"the dense ECFM Jacobian of {self.J.system.name!r} (NP + C = {self.size})",
            "pass solver='cg' or 'gmres' (matrix-free) or 'sparse-direct'",
        )
        C = self.n_forces
        Cth = self.Cth.toarray() if sp.issparse(self.Cth) else self.Cth
        return np.block([[self.J.to_dense(), self.Jl], [Cth, np.zeros((C, C))]])

    def to_sparse(self):
        return sp.bmat(
            [[self.J.to_sparse(), sp.csr_matrix(self.Jl)], [sp.csr_matrix(self.Cth), None]],
            format="csr",
        )
