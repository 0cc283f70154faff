"""Linear solves with the Galerkin Jacobian: :class:`LinearSolver` runs the plan's choice.

Every Newton step, backward-Euler step and sensitivity solve of the generic path goes
through a :class:`LinearSolver`. What it runs is decided by the solve plan
(:func:`.plan.plan_solve`), from ``solver=`` (:mod:`.options`):

``"dense"``
    Assemble :math:`J` (paper Eq. pce in block form) and LU-factorize it (LAPACK).
``"decoupled"``
    A linear system whose couplings share an eigenbasis :math:`G_q = Q D_q Q^T` splits
    into ``P`` independent ``N x N`` systems (see :meth:`GalerkinSystem.decoupling`);
    each is factorized (dense LU, or ``splu`` when the operators are sparse).
``"sparse-direct"``
    Assemble :math:`J` as ``scipy.sparse`` and factorize with ``splu``.
``"cg"`` / ``"gmres"``
    Krylov methods on the matrix-free operator (:mod:`.krylov`) with one of the
    preconditioners of :mod:`.preconditioners`: ``"mean"`` (:math:`I\\otimes\\bar K`,
    Powell & Elman 2009, the mean block factorized by ``splu`` or dense LU),
    ``"mean-amg"`` (the mean block approximated by a PyAMG V-cycle), ``"decoupled"``
    (exact on linear terms whose couplings share an eigenbasis), ``"nodal"`` (one germ:
    the ``P`` deterministic Jacobians at the germ's Gauss nodes, quadratic terms
    included) or ``"none"``.

Under the ECFM data constraint the bordered system is solved by the Schur complement on
the ``C`` forces (``C`` extra solves with :math:`J`, then a ``C x C`` LU) for the
decoupled and Krylov solvers, and assembled whole for the direct ones
(:class:`.factors.SchurFactor`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...memory import check_allocation
from ..model.operator import AugmentedOperator
from . import plan as _plan
from .factors import (  # noqa: F401  (re-exported: the v0.2 module path)
    BlockFactor,
    DenseFactor,
    SchurFactor,
    SparseFactor,
    dense_lu,
    sparse_lu,
)
from .krylov import KrylovFactor
from .options import (  # noqa: F401  (re-exported: the v0.2 module path)
    PRECONDITIONERS,
    SOLVERS,
    SolverOptions,
    solver_options,
)
from .plan import choose_solver  # noqa: F401  (re-exported: the v0.2 module path)
from .preconditioners import (  # noqa: F401  (re-exported: the v0.2 module path)
    DecoupledPreconditioner,
    MeanPreconditioner,
    NodalPreconditioner,
    make_preconditioner,
)

__all__ = ["SOLVERS", "PRECONDITIONERS", "LinearSolver", "SolverOptions", "solver_options"]


@dataclass
class LinearSolveRecord:
    """What the linear solves of one nonlinear solve did."""

    solver: str
    iterations: list = field(default_factory=list)
    residuals: list = field(default_factory=list)

    def add(self, nit, res):
        self.iterations.append(int(nit))
        self.residuals.append(float(res))


class LinearSolver:
    """Factorizes the Jacobians of one solve as its plan says and records the work.

    Parameters
    ----------
    system : GalerkinSystem
    options : SolverOptions
    constrained : bool
        Whether the solve carries the ECFM data constraint.
    steady : bool
        Steady solve (``False``: backward-Euler steps with a mass term).
    keep_factors : bool
        The caller keeps every factorization (a march for an adjoint).
    scheme : str
        The march's time scheme (:mod:`.schemes`).
    uniform : bool
        The march's steps are uniform (``False``: a given time grid).

    Attributes
    ----------
    plan : SolvePlan
        Path, linear solver and preconditioner (:func:`.plan.plan_solve`).
    """

    def __init__(
        self, system, options, *, constrained=False, steady=True, keep_factors=False,
        scheme="euler", uniform=True,
    ):  # fmt: skip
        self.system, self.options = system, options
        self.plan = _plan.plan_solve(
            system, options, constrained=constrained, steady=steady,
            keep_factors=keep_factors, scheme=scheme, uniform=uniform,
        )  # fmt: skip
        self.name = self.plan.solver
        self.record = LinearSolveRecord(self.plan.label)
        self._cache = None

    def preconditioner_kind(self):
        """The Krylov preconditioner of the plan (``None``: none or a direct solver)."""
        return self.plan.preconditioner

    @property
    def iterative(self):
        """True for the Krylov solvers (inexact Newton steps)."""
        return self.plan.iterative

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
            precond = make_preconditioner(J, self.plan.preconditioner, symmetric=name == "cg")
            inner = KrylovFactor(J, name, precond, self.options, self.record)
        if not augmented:
            return inner
        schur = SchurFactor(inner, op.Jl, op.Cth, self.options.rtol)
        return None if schur.singular else schur

    def newton_rtol(self, rnorm, tol, floor=0.0, *, linear=False):
        """Relative tolerance of a Newton step's linear solve (``None`` for direct solvers):
        the plan's forcing term :func:`.plan.newton_rtol`."""
        if not self.iterative:
            return None
        return _plan.newton_rtol(rnorm, tol, floor, linear=linear)
