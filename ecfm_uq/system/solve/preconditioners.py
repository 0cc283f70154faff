"""Preconditioners of the Krylov solves: mean-based, nodal and decoupled.

``"mean"`` / ``"mean-amg"`` (:class:`MeanPreconditioner`, Powell & Elman 2009),
``"nodal"`` (:class:`NodalPreconditioner`, one germ: the deterministic Jacobians at the
germ's Gauss nodes) and ``"decoupled"`` (:class:`DecoupledPreconditioner`, exact on
linear terms whose couplings share an eigenbasis). Each has ``apply(R)`` and
``apply_transpose(R)`` for ``R`` of shape (N, P).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import SingularSystemError
from .factors import DenseFactor, _lu_any, dense_lu
from .plan import VANISHING_BLOCK


class MeanPreconditioner:
    """:math:`(\\bar K \\otimes \\mathrm{diag}\\,\\mathbb E[\\Psi^2])^{-1}`, the mean-based preconditioner.

    Parameters
    ----------
    op : GalerkinOperator
    kind : {"mean", "mean-amg"}
    """

    def __init__(self, op, kind):
        self.N, self.P = op.N, op.P
        self.d = np.diag(op.system.E2).copy()
        K = self.K = op.mean_block()
        self.kind = kind
        scale = sum(abs(p.coef) * abs(p.term.K).max() for p in op.parts if not p.is_quadratic)
        if scale > 0 and abs(K).max() <= VANISHING_BLOCK * scale:
            raise SingularSystemError(
                f"`preconditioner`='{kind}': the mean block of the Jacobian (sum_q E[g_q] "
                "c_q K_q) vanishes: the random coefficients have zero mean, so the mean "
                "problem is singular; pass preconditioner='none' or a model with a "
                "nonzero mean operator"
            )
        if kind == "mean-amg":
            try:
                import pyamg
            except ImportError as e:  # pragma: no cover - pyamg is a core dependency
                raise ImportError("preconditioner='mean-amg' needs pyamg: pip install pyamg") from e
            K = sp.csr_matrix(K)
            try:
                ml = pyamg.smoothed_aggregation_solver(K)
            except Exception as e:  # pyamg raises several types on a bad matrix
                raise SingularSystemError(
                    f"`preconditioner`='mean-amg': multigrid setup on the mean block failed "
                    f"({type(e).__name__}: {e}); pass preconditioner='mean' or 'none'"
                ) from e
            M = ml.aspreconditioner(cycle="V")
            self._solve = lambda B: np.column_stack([M @ B[:, j] for j in range(B.shape[1])])
            self._solve_t = self._solve  # a symmetric V-cycle: its own transpose for SPD K
        else:
            factor = _lu_any(K)
            if factor is None:
                raise SingularSystemError(
                    "`preconditioner`='mean': the mean block of the Jacobian "
                    "(sum_q E[g_q] c_q K_q, the mean problem's matrix) is singular or not "
                    "finite and cannot be factorized; check that the mean coefficients make "
                    "the problem well posed, or pass preconditioner='none'"
                )
            self._solve, self._solve_t = factor.solve, factor.solve_transpose

    def apply(self, R):
        """Apply to ``R`` of shape (N, P)."""
        return self._solve(R) / self.d[None, :]

    def apply_transpose(self, R):
        """The transposed preconditioner (for adjoint solves)."""
        return self._solve_t(R) / self.d[None, :]


def _frobenius(A, B):
    """:math:`\\mathrm{tr}(A^T B)` of two (N, N) matrices, sparse or dense."""
    if sp.issparse(A):
        return float(A.multiply(B).sum())
    if sp.issparse(B):
        return float(B.multiply(A).sum())
    return float(np.vdot(A, B))


class KroneckerPreconditioner:
    """:math:`(\\bar K \\otimes A)^{-1}`, the Kronecker-product preconditioner of Ullmann (2010).

    The Jacobian is a sum of Kronecker products, :math:`J\\,\\mathrm{vec}X = \\sum_j K_j X
    C_j` (a linear term: :math:`K_q` and :math:`c_q G_q`; a quadratic term linearized at
    the state: :math:`S_k` and :math:`\\mathbb E[\\Psi\\Psi\\Psi_k]`; a
    :class:`~ecfm_uq.system.NonlinearTerm`: the user's Jacobian at each rule node and
    :math:`w_q\\Psi(\\omega_q)\\Psi(\\omega_q)^T`; the mass: :math:`M/\\Delta t` and
    :math:`\\mathbb E[\\Psi\\Psi^T]`). With the mean block :math:`\\bar K` as the spatial
    factor, the chaos factor nearest to :math:`J` in the Frobenius norm is

    .. math:: A = \\sum_j \\frac{\\langle K_j, \\bar K\\rangle_F}
              {\\langle \\bar K, \\bar K\\rangle_F}\\, C_j .

    :math:`A = \\mathbb E[\\Psi\\Psi^T]` gives the mean-based preconditioner back; the
    Kronecker one keeps how much of each random mode lies along the mean operator, for
    the same cost (one factorization of :math:`\\bar K` applied to the ``P`` columns, and
    a ``P x P`` solve). Any number of germs; for a NonlinearTerm it is built from the
    user's Jacobians at the rule's nodes.

    Parameters
    ----------
    op : GalerkinOperator
    symmetric : bool
        The Krylov method needs a symmetric positive definite preconditioner (CG): a
        chaos factor that is not positive definite is then replaced by
        :math:`\\mathbb E[\\Psi\\Psi^T]` (the mean-based preconditioner), as
        ``fallback`` records.
    """

    def __init__(self, op, symmetric=False):
        self.N, self.P = op.N, op.P
        system = op.system
        E2 = np.asarray(system.E2, dtype=float)
        mean = MeanPreconditioner(op, "mean")  # the factor of K_bar, and its checks
        self._solve, self._solve_t = mean._solve, mean._solve_t
        K = mean.K
        kk = _frobenius(K, K)
        A = np.zeros((self.P, self.P))
        for part in op.parts:
            for Kj, Cj in part.kronecker_terms():
                A += (_frobenius(Kj, K) / kk) * np.asarray(Cj)
        if op.dt is not None:
            A += (_frobenius(system.M, K) / (op.dt * kk)) * E2
        self.fallback = None
        if symmetric:
            A = 0.5 * (A + A.T)
            lam = np.linalg.eigvalsh(A)
            if not lam[0] > VANISHING_BLOCK * abs(lam).max():
                self.fallback = "chaos factor not positive definite: mean-based"
                A = E2
        # the plan's singular-pivot rule (a pivot of 1e-17 is singular, not merely nonzero)
        lu = dense_lu(A)
        if lu is None:
            self.fallback = "chaos factor singular: mean-based"
            lu = dense_lu(E2)
        self._A = DenseFactor(lu)
        self.A = A

    def apply(self, R):
        """Apply to ``R`` of shape (N, P): :math:`\\bar K^{-1} R A^{-1}`."""
        return self._A.solve_transpose(self._solve(R).T).T

    def apply_transpose(self, R):
        """The transposed preconditioner (for adjoint solves)."""
        return self._A.solve(self._solve_t(R).T).T


class _ChaosBlockDiagonal:
    """A preconditioner block-diagonal in another basis of the chaos space.

    ``R (N, P) -> solve_k((R L)[:, k]) -> X Rt``: ``P`` factorized ``N x N`` blocks
    between the transforms ``L`` and ``Rt`` (``Rt = L^{-1}``, or ``L^T`` when ``L`` is
    orthogonal); the transpose runs the same blocks transposed between ``Rt^T`` and
    ``L^T``. Subclasses set ``left``, ``right`` and ``factors``.
    """

    def _apply(self, R, left, right, transpose):
        Rh = R @ left
        X = np.column_stack(
            [
                (f.solve_transpose if transpose else f.solve)(Rh[:, k])
                for k, f in enumerate(self.factors)
            ]
        )
        return X @ right

    def apply(self, R):
        """Apply to ``R`` of shape (N, P)."""
        return self._apply(R, self.left, self.right, transpose=False)

    def apply_transpose(self, R):
        """The transposed preconditioner (for adjoint solves)."""
        return self._apply(R, self.right.T, self.left.T, transpose=True)


class NodalPreconditioner(_ChaosBlockDiagonal):
    """The Galerkin Jacobian with its chaos integrals taken by the ``P``-node Gauss rule.

    For a one-germ basis, replacing every :math:`\\mathbb E[g\\,\\Psi\\Psi^T]` and
    :math:`\\mathbb E[\\Psi_b\\Psi_c\\Psi_\\ell]` of the Jacobian by the germ's ``P``-node
    Gauss rule (:class:`ecfm_uq.chaos.GaussNodes`) gives
    :math:`B = (I\\otimes\\Phi^T W)\\,\\mathrm{blockdiag}(B_k)\\,(I\\otimes\\Phi)` with

    .. math:: B_k = \\sum_q c_q\\,g_q(\\omega_k)\\,K_q + \\sum_r c_r\\,S_r(u_k)
              + m_k M/\\Delta t,

    the deterministic Jacobian at node :math:`\\omega_k` and node state
    :math:`u_k = \\Theta\\Phi_{k,:}^T`: what collocation factorizes. ``B`` differs from
    ``J`` only by the rule's aliasing (exact for affine couplings, up to the quadratic
    terms' degree-``3p`` products), so for smooth random inputs Krylov methods converge
    in a few iterations (Burgers with a random viscosity, ``P = 5``:
    :math:`\\|I - B^{-1}J\\|_2 = 0.030`, ``benchmarks/solvers.py``). ``B^{-1}`` costs
    ``P`` factorized ``N x N`` solves and two ``P x P`` transforms.

    Parameters
    ----------
    op : GalerkinOperator

    Raises
    ------
    ValueError
        If the system's chaos basis has more than one germ.
    SingularSystemError
        If a node Jacobian cannot be factorized.
    """

    def __init__(self, op):
        system = op.system
        nodes = system.gauss_nodes()
        if nodes is None:
            raise ValueError(
                "`preconditioner`='nodal' needs a one-germ chaos basis (dim=1, P > 1); pass "
                "preconditioner='mean' or 'decoupled'"
            )
        self.nodes = nodes
        self.left, self.right = nodes.to_nodes, nodes.from_nodes
        P = op.P
        blocks = [None] * P

        def add(k, block):
            blocks[k] = block if blocks[k] is None else blocks[k] + block

        for part in op.parts:
            if getattr(part, "is_user", False):  # a NonlinearTerm: its Jacobian at the node
                U = part.Theta @ nodes.Phi.T
                for k in range(P):
                    add(k, part.node_block(nodes.nodes[k], U[:, k]))
            elif part.is_quadratic:
                U = part.Theta @ nodes.Phi.T
                for k in range(P):
                    add(k, part.coef * part.term.form.matrix(U[:, k]))
            else:
                g = nodes.coupling_values(part.term.G)
                for k in range(P):
                    add(k, (part.coef * g[k]) * part.term.K)
        if op.dt is not None:
            m = nodes.coupling_values(system.E2)
            for k in range(P):
                add(k, (m[k] / op.dt) * system.M)
        self.factors = []
        for k, B in enumerate(blocks):
            if isinstance(B, np.matrix):  # a sparse K plus a dense linearization
                B = np.asarray(B)
            factor = None if B is None else _lu_any(B)
            if factor is None:
                raise SingularSystemError(
                    f"`preconditioner`='nodal': the Jacobian at Gauss node {k} "
                    f"(omega = {nodes.nodes[k]:.4g}) is singular; pass preconditioner='mean'"
                )
            self.factors.append(factor)


class DecoupledPreconditioner(_ChaosBlockDiagonal):
    """Exact on the linear part in the couplings' common eigenbasis, mean-based on the rest.

    With :math:`G_q = Q D_q Q^T` for every linear term and for :math:`\\mathbb E[\\Psi\\Psi^T]`
    (the mass and the quadratic terms' mean blocks couple through it), the operator

    .. math:: B = \\sum_q c_q K_q\\otimes G_q
              + (M/\\Delta t + \\bar S)\\otimes\\mathbb E[\\Psi\\Psi^T]

    is ``P`` independent blocks :math:`B_p = \\sum_q c_q d_{qp} K_q + e_p(M/\\Delta t +
    \\bar S)` in that basis (:math:`\\bar S` the quadratic terms linearized at the mean
    state). For a linear system :math:`B = J` (one Krylov iteration); a random
    coefficient then costs the preconditioner nothing, and only the quadratic terms'
    fluctuation is left to the Krylov method (Burgers with a random viscosity: 5 GMRES
    iterations per Newton step at P = 5 against 12.4 with the mean block,
    ``benchmarks/solvers.py``).

    Parameters
    ----------
    op : GalerkinOperator

    Raises
    ------
    ValueError
        If the couplings have no common eigenbasis.
    SingularSystemError
        If a block cannot be factorized.
    """

    def __init__(self, op):
        from ...chaos.tensors import common_eigenbasis

        system = op.system
        E2 = np.asarray(system.E2, dtype=float)
        lin = [p for p in op.parts if not p.is_quadratic]
        quad = [p for p in op.parts if p.is_quadratic]
        found = common_eigenbasis([p.term.G for p in lin] + [E2])
        if found is None:
            raise ValueError(
                "`preconditioner`='decoupled' needs couplings E[g_q Psi Psi^T] with a common "
                "eigenbasis (e.g. every random coefficient affine in one germ); these do "
                "not have one: pass preconditioner='mean'"
            )
        Q, D = found
        self.left, self.right = Q, Q.T
        shared = None  # (M / dt + S_bar), coupled through E[Psi Psi^T]
        for part in quad:
            block = part.mean_block(E2[0, 0])
            shared = block if shared is None else shared + block
        if op.dt is not None:
            block = system.M / op.dt
            shared = block if shared is None else shared + block
        # a block whose coupling eigenvalues all vanish is singular whatever K is: the
        # Galerkin operator itself is then singular (e.g. a zero-mean coefficient alone)
        weight = np.zeros(Q.shape[0])
        for part, d in zip(lin, D[:-1], strict=True):
            weight += abs(part.coef) * np.abs(d) * abs(part.term.K).max()
        if shared is not None:
            weight += np.abs(D[-1]) * abs(shared).max()
        self.factors = []
        for k in range(Q.shape[0]):
            if weight[k] <= VANISHING_BLOCK * weight.max():
                raise SingularSystemError(
                    f"`preconditioner`='decoupled': chaos mode {k} of the decoupled operator "
                    "vanishes (every coupling's eigenvalue is zero there), so the Galerkin "
                    "operator is singular; check the random coefficients' means"
                )
            B = None
            for part, d in zip(lin, D[:-1], strict=True):
                block = (part.coef * d[k]) * part.term.K
                B = block if B is None else B + block
            if shared is not None:
                B = D[-1][k] * shared if B is None else B + D[-1][k] * shared
            if sp.issparse(B):
                B = sp.csc_matrix(B)
            factor = _lu_any(B)
            if factor is None:
                raise SingularSystemError(
                    f"`preconditioner`='decoupled': block {k} of the decoupled operator is "
                    "singular; pass preconditioner='mean' or 'none'"
                )
            self.factors.append(factor)


def make_preconditioner(op, kind, symmetric=False):
    """The Krylov preconditioner of ``kind`` for ``op`` (``None`` for ``"none"``);
    ``symmetric``: for CG (symmetric positive definite)."""
    if kind is None:
        return None
    if kind == "decoupled":
        return DecoupledPreconditioner(op)
    if kind == "nodal":
        return NodalPreconditioner(op)
    if kind == "kronecker":
        return KroneckerPreconditioner(op, symmetric=symmetric)
    return MeanPreconditioner(op, kind)
