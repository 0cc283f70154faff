"""The former home of the linear solvers, kept importable: they live in
:mod:`.solve.linear` (factorizations :mod:`.solve.factors`, preconditioners
:mod:`.solve.preconditioners`, options :mod:`.solve.options`)."""

from .solve.linear import (
    PRECONDITIONERS,
    SOLVERS,
    BlockFactor,
    DecoupledPreconditioner,
    DenseFactor,
    LinearSolver,
    MeanPreconditioner,
    NodalPreconditioner,
    SchurFactor,
    SolverOptions,
    SparseFactor,
    choose_solver,
    dense_lu,
    make_preconditioner,
    solver_options,
    sparse_lu,
)

__all__ = [
    "PRECONDITIONERS",
    "SOLVERS",
    "BlockFactor",
    "DecoupledPreconditioner",
    "DenseFactor",
    "LinearSolver",
    "MeanPreconditioner",
    "NodalPreconditioner",
    "SchurFactor",
    "SolverOptions",
    "SparseFactor",
    "choose_solver",
    "dense_lu",
    "make_preconditioner",
    "solver_options",
    "sparse_lu",
]
