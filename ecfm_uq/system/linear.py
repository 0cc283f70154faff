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

from dataclasses import dataclass, field

import numpy as np

from ..memory import check_allocation, memory_budget
from .factors import BlockFactor, DenseFactor, SchurFactor, SparseFactor, dense_lu, sparse_lu  # noqa: F401
from .krylov import KrylovFactor, _pcg  # noqa: F401
from .operator import AugmentedOperator
from .options import PRECONDITIONERS, SOLVERS, SolverOptions, _options, solver_options  # noqa: F401
from .preconditioners import (  # noqa: F401
    DecoupledPreconditioner,
    MeanPreconditioner,
    NodalPreconditioner,
    _make_preconditioner,
)

__all__ = ["SOLVERS", "PRECONDITIONERS", "LinearSolver", "SolverOptions", "solver_options"]


# "auto" assembles a dense Jacobian only below this size (LU copy included): above it a
# structured solver is faster as well as smaller.
_DENSE_AUTO_BYTES = 256 * 2**20
# "auto" preconditioner: splu of the mean block up to this N, algebraic multigrid beyond.
_SPLU_AUTO_SIZE = 400_000
# "auto" preconditioner: the decoupled or nodal one (P factorizations) up to this N
_DECOUPLED_AUTO_SIZE = 5_000
# the compiled marches (system/_kernels: march_p1, march_sg) handle N up to this
COMPILED_MARCH_MAX_N = 128


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
