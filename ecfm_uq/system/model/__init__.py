"""The stochastic Galerkin model: what a system is, below every solver.

The lowest layer of :mod:`ecfm_uq.system` (it imports nothing else of it):

* :mod:`.terms` and :mod:`.nonlinear_term` — the terms of a residual;
* :mod:`.structure` — the tables a system keeps (triple products, sparsity);
* :mod:`.galerkin` — :class:`~.galerkin.GalerkinSystem`, the immutable system;
* :mod:`.operator` — the Galerkin and augmented operators (Jacobians, matrix-free);
* :mod:`.trajectory` — :class:`~.trajectory.Trajectory`, what a march returns;
* :mod:`.thresholds` — the thresholds and status codes the solvers and kernels share.

The solvers (:mod:`ecfm_uq.system.solve`) sit on this layer, the time family
(:mod:`ecfm_uq.system.time`) on both, and :mod:`ecfm_uq.system` (steady solves and the
public names) on top.
"""
