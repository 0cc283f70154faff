"""The solve plan: the one place that decides how a Galerkin system is solved.

For a solve of a :class:`~ecfm_uq.system.GalerkinSystem` (steady or a backward-Euler
march, with or without the ECFM data constraint, with or without kept factors)
:func:`plan_solve` chooses *together*

* the **path**: the generic Newton iteration in Python (``"generic"``), the compiled
  ``P = 1`` march (``"compiled-p1"``, :func:`._kernels.march_p1`) or the compiled
  ``P > 1`` node-preconditioned march (``"compiled-sg"``, :func:`._kernels.march_sg`);
* the **linear solver** (``"dense"``, ``"decoupled"``, ``"sparse-direct"``, ``"cg"``,
  ``"gmres"``);
* the **preconditioner** of a Krylov solver (``"mean"``, ``"mean-amg"``, ``"kronecker"``,
  ``"decoupled"``, ``"nodal"`` or none),

and holds every threshold the solvers and the compiled kernels share. Nothing else in
the package makes these choices; everything else asks the plan.

Rules of ``solver="auto"``
--------------------------
``"decoupled"`` when available (steady, unconstrained, a linear system whose couplings
share an eigenbasis); ``"gmres"`` with the ``"nodal"`` preconditioner for the march of a
small nonlinear one-germ system (run by the compiled kernel, faster than the dense
:math:`(NP)^2` LU and than collocation at equal accuracy,
``benchmarks/galerkin_vs_collocation.py``); ``"dense"`` for small dense-input systems
(the paper's problems); for ``P = 1`` ``"sparse-direct"`` (sparse input) or ``"dense"``;
otherwise ``"cg"`` (symmetric linear systems) or ``"gmres"``. Sparse LU of the
chaos-coupled block matrix is never chosen for ``P > 1``: its fill makes it 30-53x slower
than mean-preconditioned CG already at ``N = 169, P = 35`` (``benchmarks/solvers.py``).
Nothing larger than the memory budget (:mod:`ecfm_uq.memory`) is chosen. A system with
a :class:`~ecfm_uq.system.NonlinearTerm` (the user's callbacks) is nonlinear and of
unknown symmetry: never ``"decoupled"`` nor ``"cg"``, never a compiled march (the
generic Newton-Krylov path takes the ``"nodal"`` preconditioner, with the user's
Jacobian at the germ's ``P`` Gauss nodes).

Rules of ``preconditioner="auto"``
----------------------------------
``"nodal"`` for a nonlinear one-germ system, else ``"decoupled"`` when the couplings
(and :math:`\\mathbb E[\\Psi\\Psi^T]`) share an eigenbasis, each for ``N <= 5000``;
else ``"mean"`` (``"mean-amg"`` beyond ``N = 400 000``). ``"kronecker"`` (Ullmann's
:math:`\\bar K\\otimes A`, as cheap as the mean-based one) is available by name: on a
lognormal conductivity (``benchmarks/fem_lognormal.py``, docs/fem.md's tables) 0-32 %
fewer CG iterations at s = 0.5 and 18-55 % at s = 1 from order 2 on (9 % more at order
1), as many on the affine fields and the nonlinear models measured; it is not the default so that what ``"auto"`` runs (and
reports) stays what it was.

Rules of ``compiled="auto"``
----------------------------
A march takes a compiled path when the kernels load (numba) and the system qualifies:
``P = 1`` with the dense solver, at most one quadratic term and ``N <= 128``; or
``P > 1`` with ``"gmres"`` + ``"nodal"`` on a one-germ system with dense operators, a
mass matrix, at most one quadratic term, ``N <= 128``, no data constraint and no kept
factors. ``compiled=True`` demands it (``ValueError`` naming what disqualifies the
system); ``compiled=False`` takes the generic path (same maths, Python per step).

Shared thresholds and the Krylov acceptance rule
-----------------------------------------------
:data:`SINGULAR_PIVOT`
    An LU pivot below this fraction of the largest makes the matrix singular (dense LU,
    sparse LU and the kernels' ``dgetrf``).
:func:`newton_rtol`
    The inexact-Newton forcing term: a Newton step's Krylov solve is taken to
    :math:`\\eta = \\min(10^{-4}, \\max(0.05\\,\\mathrm{tol}/\\|R\\|, 10^{-13}))`,
    i.e. to a linear residual of :math:`0.05\\,\\mathrm{tol}`, so that near the solution
    one step brings :math:`\\|R\\|` below ``tol``; never looser than :math:`10^{-4}`
    (fast local convergence) nor tighter than :math:`10^{-13}` (the generic path and the
    ``P > 1`` kernel alike).
:func:`krylov_accepts`
    Every Krylov solve (CG, scipy's GMRES, the kernel's GMRES) iterates to ``rtol`` on
    the residual it monitors and is **accepted when the true relative residual is at
    most** :data:`KRYLOV_ACCEPT` ``* rtol`` (the factor covers scipy's GMRES, which
    monitors the left-preconditioned residual).
:func:`scaled_tol`
    ``tol`` is absolute for models of unit scale and above and relative to the scale of
    the equations at the start of a solve (or march step) below it:
    :math:`\\mathrm{tol}\\cdot\\min(1, \\mathrm{scale})`. With the floor below, equations
    multiplied by any positive constant converge to the same answer.
:func:`residual_floor`
    Newton stops when :math:`\\|R\\| <` ``tol`` (absolute) **or**, when it is above
    ``tol``, at the round-off floor of the model's own scale
    (:meth:`GalerkinSystem.residual_scale`), so a model in any units converges. The
    floor also bounds the forcing term from below, and a Krylov answer at the round-off
    floor of :math:`|J||x|` is accepted (the generic path; the compiled marches apply
    the floor to Newton's termination and to the forcing term).
Linear systems (a Jacobian operator with ``is_linear``; :attr:`GalerkinSystem.is_linear`)
    With a Krylov solver a linear system costs **one solve**: its forcing term is not
    capped at :math:`10^{-4}` (it aims at :math:`0.05\\,\\mathrm{tol}` at once), and
    Newton stops as soon as the residual
    meets it (a start that already does, e.g. a march step's warm start, is accepted
    only below :math:`0.05\\,\\mathrm{tol}`, as good as a solve would make it). Direct
    solvers keep one refinement back-substitution after convergence.
:data:`WARM_START_STATES`
    A linear march step's Krylov solve starts from the last state plus the least-squares
    combination of the differences of this many previous states
    (:func:`.time.marching.warm_start`).
:data:`CHORD_RATE`
    Default of ``SolverOptions.chord_rate``: the ``P > 1`` kernel's chord iteration hands
    a step to Newton-Krylov once the residual falls by less than this factor per
    iteration (``0``: Newton-Krylov from the first iteration).

Outcomes
--------
:class:`SolveStatus` is the one status of a nonlinear solve, returned by the generic
Newton iteration and (as an ``int``) by the compiled kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...memory import check_allocation, memory_budget
from ..model.thresholds import (  # the shared thresholds and status codes, re-exported here
    CHORD_RATE,
    KRYLOV_ACCEPT,
    NEWTON_ETA_FACTOR,
    NEWTON_ETA_MAX,
    NEWTON_ETA_MIN,
    ROUNDOFF_FACTOR,
    SINGULAR_PIVOT,
    UNIT_ROUNDOFF,
    VANISHING_BLOCK,
    WARM_START_STATES,
    SolveStatus,
    failure_message,
)

__all__ = [
    "CHORD_RATE",
    "COMPILED_MARCH_MAX_N",
    "WARM_START_STATES",
    "KRYLOV_ACCEPT",
    "PATHS",
    "SINGULAR_PIVOT",
    "VANISHING_BLOCK",
    "SolvePlan",
    "SolveStatus",
    "choose_solver",
    "failure_message",
    "krylov_accepts",
    "newton_converged",
    "residual_floor",
    "scaled_tol",
    "newton_rtol",
    "plan_solve",
]

# -- sizes of the "auto" rules ---------------------------------------------------------
# a dense Jacobian only below this size (LU copy included): above it a structured solver
# is faster as well as smaller
DENSE_AUTO_BYTES = 256 * 2**20
# splu of the mean block up to this N, algebraic multigrid beyond
SPLU_AUTO_SIZE = 400_000
# the decoupled or nodal preconditioner (P factorizations) up to this N
DECOUPLED_AUTO_SIZE = 5_000
# the compiled marches (system/solve/_kernels: march_p1, march_sg) handle N up to this
COMPILED_MARCH_MAX_N = 128

PATHS = ("generic", "compiled-p1", "compiled-sg")
KRYLOV = ("cg", "gmres")


def residual_floor(scale, tol):
    """The round-off floor of a residual of magnitude ``scale`` when it exceeds ``tol``, else 0.

    ``scale`` is :meth:`GalerkinSystem.residual_scale` (the size of the terms the
    residual adds up): floating point cannot evaluate, let alone reduce, the residual
    below about :data:`ROUNDOFF_FACTOR` unit round-offs of it. Only a floor above the
    absolute ``tol`` matters (the model's units make ``tol`` unreachable); below it the
    absolute test decides alone, as before.
    """
    floor = ROUNDOFF_FACTOR * UNIT_ROUNDOFF * scale
    return float(floor) if floor > tol else 0.0


def scaled_tol(tol, scale):
    """Newton's tolerance for equations of magnitude ``scale`` at the start of a solve:
    ``tol`` (absolute) for models of unit scale and above, ``tol * scale`` below 1.

    Multiplying a model's equations by ``c < 1`` then changes neither its answer nor its
    iteration count (the test is relative); for ``c > 1`` the round-off floor
    (:func:`residual_floor`) does the same from above. Models of unit scale and above
    keep the absolute test they always had. A zero scale (nothing to compare with) keeps
    ``tol``.
    """
    scale = float(scale)
    if not (np.isfinite(scale) and scale > 0.0):
        return tol
    return tol * min(1.0, scale)


def newton_converged(rnorm, tol, floor=0.0):
    """Newton's termination: ``||R|| < tol`` (absolute), or ``||R||`` at the round-off
    floor of the model's own scale (:func:`residual_floor`)."""
    return bool(rnorm < tol or (floor > 0.0 and rnorm <= floor))


def newton_rtol(rnorm, tol, floor=0.0, *, linear=False):
    """The relative tolerance of a Newton step's Krylov solve (the forcing term), never
    below what floating point can reach (``floor / ||R||``).

    It aims at :data:`NEWTON_ETA_FACTOR` ``tol`` (or the floor), so one solve meets the
    Newton test on a linear system; a nonlinear step asks for at most
    :data:`NEWTON_ETA_MAX` (Newton's own convergence does the rest). A linear system
    (``linear=True``) is not capped: its one solve is the answer.
    """
    eta = max(NEWTON_ETA_FACTOR * tol / max(rnorm, 1e-300), NEWTON_ETA_MIN)
    if floor > 0.0:
        eta = max(eta, floor / max(rnorm, 1e-300))
    return float(eta if linear else min(NEWTON_ETA_MAX, eta))


def krylov_accepts(res, rtol, floor=0.0):
    """Whether a Krylov answer with true relative residual ``res`` is accepted at ``rtol``.

    ``floor``: the relative round-off floor of that residual
    (:data:`ROUNDOFF_FACTOR` unit round-offs of :math:`\\| |J||x| \\| + \\|b\\|`, over
    :math:`\\|b\\|`); an answer at it is as good as the arithmetic allows.
    """
    return bool(res == res and res <= max(KRYLOV_ACCEPT * rtol, floor))  # NaN refused


def pivots_singular(d):
    """Whether LU pivots of magnitudes ``d`` (an array) make the matrix singular."""
    if not np.all(np.isfinite(d)):
        return True
    return bool(d.min() <= SINGULAR_PIVOT * max(d.max(), 1e-300))


@dataclass(frozen=True)
class SolvePlan:
    """How one solve runs: path, linear solver and preconditioner.

    Attributes
    ----------
    path : {"generic", "compiled-p1", "compiled-sg"}
    solver : str
        The linear solver (``"auto"`` resolved).
    preconditioner : str or None
        The Krylov preconditioner (``"auto"`` resolved); ``None`` for direct solvers or
        ``preconditioner="none"``.
    options : SolverOptions
        The options the plan was made from (tolerances, limits, ``chord_rate``).
    reason : str
        Why the path runs: for a march, what keeps it off the compiled kernels (e.g.
        ``"the compiled kernels march backward Euler only (scheme='bdf2')"``) or that one
        takes it; empty for a steady solve.
    """

    path: str
    solver: str
    preconditioner: str | None
    options: object
    reason: str = ""

    @property
    def iterative(self):
        """True for the Krylov solvers (inexact Newton steps)."""
        return self.solver in KRYLOV

    @property
    def label(self):
        """What results report as ``solver``: e.g. ``"dense"``, ``"cg+mean"``,
        ``"gmres+nodal (compiled)"``."""
        name = self.solver
        if self.iterative:
            name = f"{name}+{self.preconditioner or 'none'}"
        return f"{name} (compiled)" if self.path != "generic" else name


def plan_solve(
    system, options, *, constrained=False, steady=True, keep_factors=False, scheme="euler",
    uniform=True,
):  # fmt: skip
    """The :class:`SolvePlan` of a solve of ``system`` with ``options``.

    Parameters
    ----------
    system : GalerkinSystem
    options : SolverOptions
    constrained : bool
        The solve carries the ECFM data constraint.
    steady : bool
        A steady solve (``False``: a backward-Euler march).
    keep_factors : bool
        The caller keeps every step's factors (a march for an adjoint).
    scheme : str
        The march's time scheme (:mod:`.schemes`): the compiled kernels march the
        fixed-step schemes (``"euler"``, ``"bdf2"``); ``integrate``'s variable steps
        (``"bdf"``) run on the generic path.
    uniform : bool
        The march's steps are uniform (``False``: a given grid, ``march(..., times=...)``,
        which runs on the generic path).

    Raises
    ------
    ValueError
        A named solver, preconditioner or ``compiled=True`` that cannot work here.
    MemoryBudgetError
        No solver fits the memory budget.
    """
    solver = choose_solver(
        system, options, constrained=constrained, steady=steady, keep_factors=keep_factors
    )
    precond = _preconditioner(system, options) if solver in KRYLOV else None
    path, reason = "generic", ""
    if not steady:
        path, reason = _march_path(
            system, options, solver, precond, constrained, keep_factors, scheme, uniform
        )
    return SolvePlan(path, solver, precond, options, reason)


def choose_solver(system, options, *, constrained=False, steady=True, keep_factors=False):
    """The linear solver ``options.solver`` resolves to for ``system`` (see the module rules).

    Raises ``ValueError`` for a named solver that cannot work on this system and
    :class:`~ecfm_uq.errors.MemoryBudgetError` when no solver fits the budget.
    """
    name = options.solver
    N, P = system.shape
    st = system.structure
    n = N * P + (system.n_forces if constrained else 0)
    if name == "decoupled":
        if not steady or st.decoupling is None:
            raise ValueError(
                "`solver`='decoupled' needs a steady linear system whose stochastic "
                "couplings share an eigenbasis (e.g. affine in one germ); use 'auto'"
            )
        return name
    if name == "cg":
        asym = st.asymmetry(steady)
        if asym is not None:
            raise ValueError(
                f"`solver`='cg' needs a symmetric positive definite Jacobian, but {asym}; "
                "use solver='gmres'"
            )
        return name
    if name != "auto":
        return name
    if steady and not constrained and st.decoupling is not None:
        return "decoupled"
    if (
        not steady
        and not constrained
        and not keep_factors
        and not st.is_linear
        and options.preconditioner in ("auto", "nodal")
        and _nodal_march_refusal(system) is None
    ):
        return "gmres"
    dense_bytes = 16.0 * n * n  # matrix + LU copy
    if not st.sparse_input and dense_bytes <= min(memory_budget(), DENSE_AUTO_BYTES):
        return "dense"
    if P == 1:
        # the deterministic case: the Jacobian is the spatial operator itself
        return "sparse-direct" if st.sparse_input else "dense"
    method = "cg" if st.asymmetry(steady) is None else "gmres"
    vectors = 8 if method == "cg" else min(options.restart, n) + 6
    check_allocation(
        8.0 * vectors * n, f"Krylov work vectors for NP = {n}", "reduce the chaos order or the mesh"
    )
    return method


def _preconditioner(system, options):
    """The Krylov preconditioner ``options.preconditioner`` resolves to (``None``: none)."""
    kind = options.preconditioner
    if kind == "none":
        return None
    st = system.structure
    if kind != "auto":
        return kind
    small = system.N <= DECOUPLED_AUTO_SIZE
    if small and not st.is_linear and st.gauss_nodes is not None:
        return "nodal"
    if small and st.couplings_decouple:
        return "decoupled"
    return "mean" if system.N <= SPLU_AUTO_SIZE else "mean-amg"


def _nodal_march_refusal(system):
    """Why the compiled ``P > 1`` march cannot take ``system`` (``None``: it can)."""
    st = system.structure
    N, P = system.shape
    if P == 1:
        return "P = 1"
    if st.nonlinear_terms:
        return "the system has a NonlinearTerm (a user's callbacks, evaluated in Python)"
    if st.gauss_nodes is None:
        return "the chaos basis has more than one germ (no P-node Gauss rule)"
    if st.n_quadratic > 1:
        return "the system has more than one quadratic term"
    if st.sparse_input:
        return "an operator is scipy.sparse"
    if system.M is None:
        return "the system has no mass matrix"
    if N > COMPILED_MARCH_MAX_N:
        return f"N = {N} > {COMPILED_MARCH_MAX_N}"
    return None


def _march_refusal(
    system, solver, precond, constrained, keep_factors, scheme="euler", uniform=True
):
    """Why no compiled march takes this solve (``None``: one can)."""
    N, P = system.shape
    if scheme not in ("euler", "bdf2"):
        return f"the compiled kernels march fixed-step schemes only (scheme={scheme!r})"
    if not uniform:
        return "the compiled kernels march uniform steps only (a grid was given: times=)"
    if P == 1:
        if solver != "dense":
            return f"the P = 1 kernel factorizes densely, but the solver is {solver!r}"
        if system.structure.nonlinear_terms:
            return "the system has a NonlinearTerm (a user's callbacks, evaluated in Python)"
        if system.structure.n_quadratic > 1:
            return "the system has more than one quadratic term"
        if N > COMPILED_MARCH_MAX_N:
            return f"N = {N} > {COMPILED_MARCH_MAX_N}"
        return None
    if solver != "gmres" or precond != "nodal":
        return f"the P > 1 kernel runs gmres+nodal, but the plan is {solver}+{precond}"
    if constrained:
        return "the P > 1 kernel has no data constraint"
    if keep_factors:
        return "the P > 1 kernel keeps no factors for an adjoint"
    return _nodal_march_refusal(system)


def _march_path(system, options, solver, precond, constrained, keep_factors, scheme, uniform):
    """``(path, reason)`` of a march: a compiled kernel's path, or ``"generic"`` and why."""
    if options.compiled is False:
        return "generic", "compiled=False asks for the generic march"
    from .compiled import compiled_kernels  # the kernels' loader (numba, on first use)

    refusal = _march_refusal(system, solver, precond, constrained, keep_factors, scheme, uniform)
    if refusal is None and compiled_kernels() is None:
        refusal = "the compiled kernels do not load with this numba"
    if refusal is not None:
        if options.compiled is True:
            raise ValueError(
                f"`compiled`=True but no compiled march takes this solve: {refusal}; "
                "pass compiled='auto' (or False) for the generic march"
            )
        return "generic", refusal
    return ("compiled-p1" if system.P == 1 else "compiled-sg"), "a compiled kernel takes it"


def dense_unknowns(system, *args, **kwargs):
    """Unknowns of the largest dense system a solve of ``system`` factorizes, or ``None``
    for sparse or matrix-free work (its BLAS calls are small): the size
    :func:`ecfm_uq.threads.blas_threads` decides the BLAS threads by."""
    if system.structure.sparse_input:
        return None
    return system.N * system.P
