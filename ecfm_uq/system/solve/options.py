"""Options of the linear solves: ``solver=`` as a name, a dict or :class:`SolverOptions`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..._validation import check_choice, check_int, check_positive, check_real
from .plan import CHORD_RATE

__all__ = ["SOLVERS", "PRECONDITIONERS", "SolverOptions", "solver_options"]

SOLVERS = ("auto", "dense", "decoupled", "sparse-direct", "cg", "gmres")
PRECONDITIONERS = ("auto", "mean", "mean-amg", "kronecker", "decoupled", "nodal", "none")


@dataclass(frozen=True)
class SolverOptions:
    """How the linear systems of a solve are handled.

    Parameters
    ----------
    solver : {"auto", "dense", "decoupled", "sparse-direct", "cg", "gmres"}
    preconditioner : {"auto", "mean", "mean-amg", "kronecker", "decoupled", "nodal", "none"}
        For ``"cg"``/``"gmres"``: the mean-based preconditioner with the mean block
        factorized by ``splu`` (``"mean"``) or approximated by one AMG V-cycle
        (``"mean-amg"``, needs ``pyamg``); ``"kronecker"``, the mean block times the
        chaos factor nearest the Jacobian (Ullmann; same cost as ``"mean"``, any number
        of germs, built from the user's node Jacobians for a NonlinearTerm);
        or ``"decoupled"``, exact for the linear terms
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
    compiled : {"auto", True, False}
        Marches only: run a compiled kernel when one takes the system (``"auto"``),
        demand it (``True``: ``ValueError`` saying why none does) or take the generic
        Python path (``False``); see :mod:`.plan`.
    chord_rate : float in [0, 1]
        The compiled ``P > 1`` march iterates each step with the node-wise preconditioner
        as a chord method and switches to Newton-Krylov once the residual falls by less
        than this factor per iteration; ``0``: Newton-Krylov from the first iteration.

    Notes
    -----
    Which path, solver and preconditioner run, and every threshold they share (the
    singular pivot, the inexact-Newton forcing term, the Krylov acceptance rule), are
    decided in one place, :mod:`ecfm_uq.system.solve.plan`.
    """

    solver: str = "auto"
    preconditioner: str = "auto"
    rtol: float = 1e-10
    maxiter: int = 500
    restart: int = 50
    compiled: str | bool = "auto"
    chord_rate: float = CHORD_RATE

    def __post_init__(self):
        check_choice("solver", self.solver, SOLVERS)
        check_choice("preconditioner", self.preconditioner, PRECONDITIONERS)
        check_positive("rtol", self.rtol)
        check_int("maxiter", self.maxiter, minimum=1)
        check_int("restart", self.restart, minimum=1)
        if not (self.compiled == "auto" or self.compiled is True or self.compiled is False):
            raise ValueError(f"`compiled` must be 'auto', True or False, got {self.compiled!r}")
        rate = check_real("chord_rate", self.chord_rate)
        if not 0.0 <= rate <= 1.0:
            raise ValueError(
                f"`chord_rate` must lie in [0, 1] (0: Newton-Krylov throughout), got {rate}"
            )


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
