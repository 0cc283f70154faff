"""The solvers of a Galerkin system: one layer above :mod:`ecfm_uq.system.model`.

* :mod:`.plan` — the solve plan (which solver, preconditioner, march path);
* :mod:`.options` — :class:`~.options.SolverOptions`, the solver settings;
* :mod:`.linear` — :class:`~.linear.LinearSolver` over :mod:`.factors` (direct),
  :mod:`.krylov` (CG, GMRES) and :mod:`.preconditioners`;
* :mod:`.nonlinear` — Newton's method, bordered by the ECFM data constraint;
* :mod:`.compiled` — the compiled marches (numba kernels of :mod:`._kernels`).

It imports only :mod:`ecfm_uq.system.model` below it; the time family
(:mod:`ecfm_uq.system.time`) and the steady solves (:mod:`ecfm_uq.system.steady`) sit on
it.
"""
