"""Linear solves with the Galerkin Jacobian: the one place that picks dense, sparse or Krylov.

Every Newton step, backward-Euler step and sensitivity solve of :mod:`.solvers` goes
through a :class:`LinearSolver`, selected by ``solver=``:

``"dense"``
    Assemble :math:`J` (paper Eq. pce in block form) and LU-factorize it (LAPACK).
``"decoupled"``
    A linear system whose couplings share an eigenbasis :math:`G_q = Q D_q Q^T` splits
    into ``P`` independent ``N x N`` systems (see :meth:`GalerkinSystem.decoupling`);
    each is factorized (dense LU, or ``splu`` when the operators are sparse).
``"sparse-direct"``
    Assemble :math:`J` as ``scipy.sparse`` and factorize with ``splu``.
``"cg"`` / ``"gmres"``
    Krylov methods on the matrix-free operator with the mean-based (block-diagonal)
    preconditioner :math:`I\\otimes\\bar K` (Powell & Elman 2009): :math:`\\bar K`, the
    Jacobian of the mean problem, is factorized once (``"mean"``: ``splu`` or dense LU;
    ``"mean-amg"``: a PyAMG smoothed-aggregation V-cycle) and applied to all ``P`` chaos
    columns at once. Iterations are nearly independent of ``N``. Or ``"decoupled"``
    (exact on linear terms whose couplings share an eigenbasis) or ``"nodal"`` (one
    germ: the ``P`` deterministic Jacobians at the germ's Gauss nodes, quadratic terms
    included; :class:`NodalPreconditioner`).
``"auto"`` (default)
    ``"decoupled"`` when available (steady, unconstrained); ``"gmres"`` with the
    ``"nodal"`` preconditioner for the backward-Euler march of a small nonlinear
    one-germ system (run by a compiled kernel, :func:`nodal_march_eligible`); ``"dense"`` for small
    dense-input systems (the paper's problems, unchanged); for ``P = 1`` ``"sparse-direct"``
    (sparse input) or ``"dense"``; otherwise ``"cg"`` (symmetric linear systems) or
    ``"gmres"``. Sparse LU of the chaos-coupled block matrix is never chosen for
    ``P > 1``: its fill makes it 30-53x slower than mean-preconditioned CG already at
    ``N = 169, P = 35`` (``benchmarks/solvers.py``). Nothing larger than the memory budget (:mod:`ecfm_uq.memory`)
    is chosen.

Under the ECFM data constraint the bordered system is solved by the Schur complement on
the ``C`` forces (``C`` extra solves with :math:`J`, then a ``C x C`` LU) for the
decoupled and Krylov solvers, and assembled whole for the direct ones.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validation import check_choice, check_int, check_positive
from ..errors import KrylovError, SingularSystemError
from ..memory import check_allocation, memory_budget
from .operator import AugmentedOperator

__all__ = ["SOLVERS", "PRECONDITIONERS", "LinearSolver", "SolverOptions", "solver_options"]

SOLVERS = ("auto", "dense", "decoupled", "sparse-direct", "cg", "gmres")
PRECONDITIONERS = ("auto", "mean", "mean-amg", "decoupled", "nodal", "none")

# "auto" assembles a dense Jacobian only below this size (LU copy included): above it a
# structured solver is faster as well as smaller.
_DENSE_AUTO_BYTES = 256 * 2**20
# "auto" preconditioner: splu of the mean block up to this N, algebraic multigrid beyond.
_SPLU_AUTO_SIZE = 400_000
# "auto" preconditioner: the decoupled or nodal one (P factorizations) up to this N
_DECOUPLED_AUTO_SIZE = 5_000
# the compiled marches (system/_kernels: march_p1, march_sg) handle N up to this
COMPILED_MARCH_MAX_N = 128


@dataclass(frozen=True)
class SolverOptions:
    """How the linear systems of a solve are handled.

    Parameters
    ----------
    solver : {"auto", "dense", "decoupled", "sparse-direct", "cg", "gmres"}
    preconditioner : {"auto", "mean", "mean-amg", "decoupled", "none"}
        For ``"cg"``/``"gmres"``: the mean-based preconditioner with the mean block
        factorized by ``splu`` (``"mean"``) or approximated by one AMG V-cycle
        (``"mean-amg"``, needs ``pyamg``); or ``"decoupled"``, exact for the linear terms
        when their couplings share an eigenbasis (``P`` factorized ``N x N`` blocks) and
        mean-based for the quadratic ones; or ``"nodal"`` (one germ): the Jacobian with
        its chaos integrals taken by the germ's ``P``-node Gauss rule, i.e. the ``P``
        deterministic Jacobians at the nodes, quadratic terms included.
        ``"auto"``: ``"nodal"`` for a nonlinear one-germ system, else ``"decoupled"``
        when available, each for ``N <= 5000``; else ``"mean"`` (``"mean-amg"`` for very
        large ``N``).
    rtol : float
        Relative residual of Krylov solves outside Newton (sensitivities, adjoints).
        Newton steps choose their own, tighter as the residual approaches ``tol``.
    maxiter : int
        Krylov iterations per solve.
    restart : int
        GMRES restart length.
    """

    solver: str = "auto"
    preconditioner: str = "auto"
    rtol: float = 1e-10
    maxiter: int = 500
    restart: int = 50

    def __post_init__(self):
        check_choice("solver", self.solver, SOLVERS)
        check_choice("preconditioner", self.preconditioner, PRECONDITIONERS)
        check_positive("rtol", self.rtol)
        check_int("maxiter", self.maxiter, minimum=1)
        check_int("restart", self.restart, minimum=1)


def _options(**kw):
    """SolverOptions(**kw) with an unknown option named and the known ones listed."""
    known = [f.name for f in dataclasses.fields(SolverOptions)]
    unknown = sorted(set(kw) - set(known))
    if unknown:
        raise TypeError(
            f"`solver` has unknown option(s) {unknown}; known options are {known} "
            "(Newton's `tol`/`maxiter` are arguments of the solve itself)"
        )
    return SolverOptions(**kw)


def solver_options(solver="auto", **kw):
    """Normalize ``solver=`` (a name, a :class:`SolverOptions` or a dict) to SolverOptions."""
    if isinstance(solver, SolverOptions):
        return solver if not kw else _options(**{**solver.__dict__, **kw})
    if isinstance(solver, dict):
        return _options(**{**solver, **kw})
    if isinstance(solver, str):
        return _options(solver=solver, **kw)
    raise TypeError(
        f"`solver` must be a name from {SOLVERS}, a SolverOptions or a dict, "
        f"got {type(solver).__name__}"
    )


# --------------------------------------------------------------------------------------
# factors: objects with solve(rhs, rtol=None) for rhs (n,) or (n, m)
# --------------------------------------------------------------------------------------
def dense_lu(J):
    """LU factors of a dense matrix, or ``None`` when it is singular or not finite."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sla.LinAlgWarning)
        lu = sla.lu_factor(J, check_finite=False)
    # lu_factor only warns on exact singularity; detect it ourselves
    d = np.abs(np.diag(lu[0]))
    if not np.all(np.isfinite(d)) or d.min() <= 1e-14 * max(d.max(), 1e-300):
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
    if not np.all(np.isfinite(d)) or d.min() <= 1e-14 * max(d.max(), 1e-300):
        return None
    return lu


class DenseFactor:
    """LU factors of a dense matrix."""

    def __init__(self, lu):
        self.lu = lu

    def solve(self, rhs, rtol=None):
        return sla.lu_solve(self.lu, rhs, check_finite=False)

    def solve_transpose(self, rhs, rtol=None):
        """Solve with the transposed matrix (adjoint equations)."""
        return sla.lu_solve(self.lu, rhs, trans=1, check_finite=False)


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
        K = op.mean_block()
        self.kind = kind
        scale = sum(abs(p.coef) * abs(p.term.K).max() for p in op.parts if not p.is_quadratic)
        if scale > 0 and abs(K).max() <= 1e-12 * scale:
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
            if part.is_quadratic:
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
        from ..chaos.tensors import common_eigenbasis

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
            if weight[k] <= 1e-12 * weight.max():
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


def _make_preconditioner(op, kind):
    """The Krylov preconditioner of ``kind`` for ``op`` (``None`` for ``"none"``)."""
    if kind is None:
        return None
    if kind == "decoupled":
        return DecoupledPreconditioner(op)
    if kind == "nodal":
        return NodalPreconditioner(op)
    return MeanPreconditioner(op, kind)


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
        """Solve with :math:`J^T` (adjoint equations), same preconditioner transposed."""
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
        # GMRES stops on its preconditioned residual; accept the true one within 10x
        if not np.isfinite(res) or res > (rtol if self.method == "cg" else 10 * rtol):
            raise KrylovError(
                f"{self.method} did not reach rtol={rtol:.1e}: relative residual {res:.3e} "
                f"after {nit} iterations (raise maxiter, or try another preconditioner)"
            )
        return X.ravel()

    def solve(self, rhs, rtol=None):
        rtol = self.options.rtol if rtol is None else rtol
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 1:
            return self._solve_one(rhs, rtol)
        return np.column_stack([self._solve_one(rhs[:, j], rtol) for j in range(rhs.shape[1])])


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


# --------------------------------------------------------------------------------------
# the solver: choice, factorization, record
# --------------------------------------------------------------------------------------
@dataclass
class LinearSolveRecord:
    """What the linear solves of one nonlinear solve did."""

    solver: str
    iterations: list = field(default_factory=list)
    residuals: list = field(default_factory=list)

    def add(self, nit, res):
        self.iterations.append(int(nit))
        self.residuals.append(float(res))


def _krylov_bytes(options, method, n):
    vectors = 8 if method == "cg" else min(options.restart, n) + 6
    return 8.0 * vectors * n


def nodal_march_eligible(system):
    """Whether the compiled stochastic Galerkin march (``_kernels.march_sg``) handles ``system``.

    A one-germ chaos basis with ``P > 1``, dense operators of the library's term types
    (linear, at most one quadratic, loads), a mass matrix and ``N <= 128``.
    """
    from .terms import QuadraticTerm

    N, P = system.shape
    n_quad = sum(isinstance(t, QuadraticTerm) for t in system.terms)
    return (
        P > 1
        and system.gauss_nodes() is not None
        and n_quad <= 1
        and not system.sparse_input
        and system.M is not None
        and N <= COMPILED_MARCH_MAX_N
    )


def choose_solver(system, options, *, constrained=False, steady=True, keep_factors=False):
    """Resolve ``options.solver`` for ``system``; the one place this choice is made.

    ``keep_factors``: the caller keeps every factorization (a march for an adjoint).
    Raises ``ValueError`` for a named solver that cannot work on this system and
    :class:`~ecfm_uq.errors.MemoryBudgetError` when no solver fits the budget.
    """
    name = options.solver
    N, P = system.shape
    n = N * P + (system.n_forces if constrained else 0)
    if name == "decoupled":
        if not steady or system.decoupling() is None:
            raise ValueError(
                "`solver`='decoupled' needs a steady linear system whose stochastic "
                "couplings share an eigenbasis (e.g. affine in one germ); use 'auto'"
            )
        return name
    if name == "cg":
        asym = _system_asymmetry(system, steady)
        if asym is not None:
            raise ValueError(
                f"`solver`='cg' needs a symmetric positive definite Jacobian, but {asym}; "
                "use solver='gmres'"
            )
        return name
    if name != "auto":
        return name
    if steady and not constrained and system.decoupling() is not None:
        return "decoupled"
    if (
        not steady
        and not constrained
        and not keep_factors
        and not system.is_linear
        and options.preconditioner in ("auto", "nodal")
        and nodal_march_eligible(system)
    ):
        # a nonlinear one-germ march: node-preconditioned iterations in the compiled
        # kernel, faster than the dense (NP)^2 LU and than collocation at equal accuracy
        # (benchmarks/galerkin_vs_collocation.py)
        return "gmres"
    budget = memory_budget()
    dense_bytes = 16.0 * n * n  # matrix + LU copy
    if not system.sparse_input and dense_bytes <= min(budget, _DENSE_AUTO_BYTES):
        return "dense"
    if P == 1:
        # the deterministic case: the Jacobian is the spatial operator itself
        return "sparse-direct" if system.sparse_input else "dense"
    method = "cg" if _system_asymmetry(system, steady) is None else "gmres"
    need = _krylov_bytes(options, method, n)
    check_allocation(
        need,
        f"Krylov work vectors for NP = {n}",
        "reduce the chaos order or the mesh",
    )
    return method


def _system_asymmetry(system, steady):
    if not system.is_linear:
        return "the system has a quadratic (nonsymmetric) term"
    from .terms import LinearTerm

    for term in system.terms:
        if isinstance(term, LinearTerm) and not term.is_symmetric():
            return f"term {term.name!r} has a non-symmetric K or G"
    if not steady and system.M is not None and not system.mass_is_symmetric():
        return "the mass matrix M is not symmetric"
    return None


class LinearSolver:
    """Factorizes the Jacobians of one solve with the chosen method and records the work.

    Parameters
    ----------
    system : GalerkinSystem
    options : SolverOptions
    constrained : bool
        Whether the solve carries the ECFM data constraint.
    steady : bool
        Steady solve (``False``: backward-Euler steps with a mass term).
    """

    def __init__(self, system, options, *, constrained=False, steady=True, keep_factors=False):
        self.system, self.options = system, options
        self.name = choose_solver(
            system, options, constrained=constrained, steady=steady, keep_factors=keep_factors
        )
        self.record = LinearSolveRecord(self._label())
        self._cache = None

    def _label(self):
        if self.name not in ("cg", "gmres"):
            return self.name
        return f"{self.name}+{self.preconditioner_kind() or 'none'}"

    def preconditioner_kind(self):
        """The Krylov preconditioner ``"auto"`` resolves to (``None``: none)."""
        kind = self.options.preconditioner
        if kind == "none":
            return None
        if kind == "auto":
            small = self.system.N <= _DECOUPLED_AUTO_SIZE
            if small and not self.system.is_linear and self.system.gauss_nodes() is not None:
                return "nodal"
            if small and self._couplings_decouple():
                return "decoupled"
            return "mean" if self.system.N <= _SPLU_AUTO_SIZE else "mean-amg"
        return kind

    def _couplings_decouple(self):
        """Whether the linear terms' couplings and E[Psi Psi^T] share an eigenbasis."""
        from ..chaos.tensors import common_eigenbasis
        from .terms import LinearTerm

        if not hasattr(self, "_decouples"):
            system = self.system
            Gs = [t.G for t in system.terms if isinstance(t, LinearTerm)]
            self._decouples = system.P > 1 and common_eigenbasis([*Gs, system.E2]) is not None
        return self._decouples

    @property
    def iterative(self):
        """True for the Krylov solvers (inexact Newton steps)."""
        return self.name in ("cg", "gmres")

    def factorize(self, op):
        """Factors of ``op`` (GalerkinOperator or AugmentedOperator), or ``None`` if singular.

        For a linear system the same operator object comes back for the same
        parameters (:meth:`GalerkinSystem.jacobian_operator`), and its factors are reused.
        """
        if isinstance(op, np.ndarray):  # a caller's own dense Jacobian
            lu = dense_lu(op)
            return None if lu is None else DenseFactor(lu)
        if self._cache is not None and self._cache[0] is op and op.is_linear:
            return self._cache[1]
        factor = self._factorize(op)
        self._cache = (op, factor) if op.is_linear else None
        return factor

    def _factorize(self, op):
        name = self.name
        augmented = isinstance(op, AugmentedOperator)
        if name == "dense":
            lu = dense_lu(op.to_dense())
            return None if lu is None else DenseFactor(lu)
        if name == "sparse-direct":
            A = op.to_sparse()
            # splu fill is unknown beforehand; refuse at least what we know it needs
            check_allocation(
                12.0 * A.nnz * 4,
                f"sparse LU of the block Jacobian (NP = {op.size}, nnz = {A.nnz})",
                "pass solver='cg' or 'gmres'",
            )
            lu = sparse_lu(A)
            return None if lu is None else SparseFactor(lu)
        J = op.J if augmented else op
        if name == "decoupled":
            Q, D = self.system.decoupling()
            try:
                inner = BlockFactor(J, Q, D)
            except np.linalg.LinAlgError:
                return None
        else:
            precond = _make_preconditioner(J, self.preconditioner_kind())
            inner = KrylovFactor(J, name, precond, self.options, self.record)
        if not augmented:
            return inner
        schur = SchurFactor(inner, op.Jl, op.Cth, self.options.rtol)
        return None if schur.singular else schur

    def newton_rtol(self, rnorm, tol):
        """Relative tolerance of a Newton step's linear solve (``None`` for direct solvers).

        Tight enough that one step brings ``||R||`` well below ``tol`` near the solution,
        loose (1e-4) far from it: an inexact Newton method that keeps fast local convergence.
        """
        if not self.iterative:
            return None
        return float(min(1e-4, max(0.05 * tol / max(rnorm, 1e-300), 1e-13)))

    def summary(self):
        """A one-line account: solver and Krylov iterations."""
        it = self.record.iterations
        if not it:
            return self.record.solver
        return f"{self.record.solver}, {len(it)} Krylov solves, iterations {min(it)}-{max(it)}"
