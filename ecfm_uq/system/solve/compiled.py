"""The compiled marches: inputs for :mod:`._kernels`, their outputs as a :class:`Trajectory`.

The plan (:func:`.plan.plan_solve`) decides that a march runs here (path
``"compiled-p1"`` or ``"compiled-sg"``); this module stacks the system's fixed tables
(kept in ``system.structure``), evaluates the parameter-dependent ones, calls the kernel
and translates its integer status (:class:`.plan.SolveStatus`) into the trajectory's
status and message, exactly as the generic march reports a failed step.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model.terms import LoadTerm
from ..model.thresholds import SolveStatus, failure_message
from ..model.trajectory import Trajectory

# the compiled kernels: loaded once, given up once if numba cannot run them
_KERNELS = {"module": None, "failed": False}


def compiled_kernels():
    """The module of compiled kernels, or ``None`` where it cannot work.

    The kernels reach LAPACK through numba's own binding (``numba.np.linalg``), which is
    numba-internal: if a numba release moves it, every march takes the generic Python
    path (same results, slower) instead of failing.
    """
    if _KERNELS["failed"]:
        return None
    if _KERNELS["module"] is None:
        try:
            from . import _kernels
        except (ImportError, AttributeError):
            _KERNELS["failed"] = True
            return None
        _KERNELS["module"] = _kernels
    return _KERNELS["module"]


def kernels_failed():
    """Record that a kernel did not compile with this numba: later plans go generic."""
    _KERNELS["failed"] = True


def compiled_march(linear, system, eps, Theta0, dt, n_steps, t0, M_obs, V, sens, tol, maxiter,
                   keep, guess, scheme, rules):  # fmt: skip
    """March on the plan's compiled path; ``None`` if the kernel does not compile.

    The step rules ``rules[s] = (h_s, w_s)`` of the method ``scheme`` on the fixed grid
    (:meth:`.time.base.Stepper.rules`) reach the kernels as the mass term of the
    two-step steps, ``Mdt2``, which steps use it (``hsel``) and the weights of the states
    each step starts from (``wts``).

    ``linear.plan.path`` is ``"compiled-p1"`` (:func:`._kernels.march_p1`: ``P = 1``,
    dense, data constraint, sensitivities and kept factors allowed) or ``"compiled-sg"``
    (:func:`._kernels.march_sg`: ``P > 1``, node-preconditioned GMRES).
    """
    _kernels = compiled_kernels()
    if _kernels is None:
        return None
    N, P = system.shape
    st = system.structure
    lin, quads = st.linear_terms, st.quadratic_terms
    loads = [t for t in system.terms if isinstance(t, LoadTerm)]
    n_eps = system.n_eps
    times = t0 + dt * np.arange(n_steps + 1)
    Ks = st.stacked_K
    if quads:
        rows, ptr, idx, val = quads[0].linearization_table()
        cq, gq = quads[0].coef.value(eps), np.asarray(quads[0].coef.grad(eps), dtype=float)
    else:
        rows = idx = np.zeros(0, dtype=np.int64)
        ptr = np.zeros(1, dtype=np.int64)
        val, cq, gq = np.zeros(0), 0.0, np.zeros(n_eps)
    F = np.zeros((n_steps + 1, N, P))
    dF = np.zeros((n_steps + 1, N, P, n_eps))
    for term in loads:
        Ft, dFt = term.on_grid(eps, times, derivative=sens or keep)
        F += Ft
        if dFt is not None:
            dF += dFt
    Mdt = system.mass_matrix() / dt if P == 1 else system.M / dt
    h2 = next((h for h, _ in rules if h != dt), dt)
    Mdt2 = system.mass_matrix() / h2 if P == 1 else system.M / h2
    hsel = np.array([0 if h == dt else 1 for h, _ in rules], dtype=np.int64)
    wts = np.zeros((n_steps, 2))
    for s, (_, w) in enumerate(rules):
        wts[s, : len(w)] = w
    steps = (np.ascontiguousarray(Mdt2), hsel, wts)
    quad = (rows, ptr, idx, val, float(cq), gq)
    args = (system, eps, Theta0, times, sens, tol, maxiter, guess)
    from numba.core.errors import NumbaError

    try:
        with np.errstate(all="ignore"):
            if P == 1:
                F1, dF1 = np.ascontiguousarray(F[:, :, 0]), np.ascontiguousarray(dF[:, :, 0])
                traj = _march_p1(
                    _kernels, linear, *args, M_obs, V, keep, lin, Ks, quad, F1, dF1, Mdt, steps
                )
            else:
                traj = _march_sg(_kernels, linear, *args, lin, Ks, quad, F, dF, Mdt, steps)
            traj.plan, traj.scheme = linear.plan, scheme  # the path that ran, and why
            return traj
    except NumbaError:  # the kernel does not compile with this numba: use the generic march
        kernels_failed()
        return None


def _failed_trajectory(system, times, failed, status, rnorm, maxiter, Theta, lam, nits, label,
                       its=()):  # fmt: skip
    """The trajectory up to a compiled march's failed step, with its status and reason."""
    status = SolveStatus(status)
    k = failed + 1
    reason = failure_message(status, maxiter)
    msg = f"{system.name}: Newton failed at step {k} (t={times[k]:.6g}) with ||R||={rnorm:.3e}: {reason}"
    return Trajectory(
        times[:k], Theta[:k], lam[:k], None, None, False, msg, k, nits[:k], label, list(its[:k]),
        status=status,
    )  # fmt: skip


def _march_sg(_kernels, linear, system, eps, Theta0, times, sens, tol, maxiter, guess, lin, Ks,
              quad, F, dF, Mdt, steps):  # fmt: skip
    """The ``P > 1`` compiled march (:func:`_kernels.march_sg`)."""
    N, P = system.shape
    n_eps = system.n_eps
    nodes = system.structure.gauss_nodes
    Gs, gnode, mnode, E3m = system.structure.nodal_tables
    cs = np.array([t.coef.value(eps) for t in lin], dtype=float).reshape(len(lin))
    gK = np.array([t.coef.grad(eps) for t in lin], dtype=float).reshape(len(lin), n_eps)
    rows, ptr, idx, val, cq, gq = quad
    start = np.zeros((1, N, P)) if guess is None else np.ascontiguousarray(guess.Theta)
    opts = linear.options
    Th, dTh, nits, kits, failed, status, rnorm = _kernels.march_sg(
        np.ascontiguousarray(Mdt), np.ascontiguousarray(system.E2), Ks, cs, Gs, gK,
        rows, ptr, idx, val, cq, gq, E3m, F, dF,
        np.ascontiguousarray(nodes.Phi.T), nodes.to_nodes, nodes.from_nodes, mnode, gnode,
        np.ascontiguousarray(Theta0), start, guess is not None, tol, maxiter, bool(sens),
        opts.rtol, opts.restart, opts.maxiter, opts.chord_rate, *steps,
    )  # fmt: skip
    label = linear.plan.label
    lam = np.zeros((len(times), 0))
    if failed != -1:
        return _failed_trajectory(
            system, times, failed, status, rnorm, maxiter, Th, lam, nits, label, kits
        )
    return Trajectory(
        times, Th, lam, dTh if sens else None, None, True, "converged at every step", None,
        nits, label, [int(k) for k in kits],
    )  # fmt: skip


def _march_p1(_kernels, linear, system, eps, Theta0, times, sens, tol, maxiter, guess, M_obs, V,
              keep, lin, Ks, quad, F, dF, Mdt, steps):  # fmt: skip
    """The ``P = 1`` compiled march (:func:`_kernels.march_p1`) and its adjoint."""
    N = system.N
    n_eps = system.n_eps
    n_steps = len(times) - 1
    # with P = 1 the coupling G = E[g Psi_0 Psi_0] is a scalar factor of the term
    g00 = np.array([t.G[0, 0] for t in lin])
    cs = np.array([t.coef.value(eps) for t in lin]) * g00
    gK = np.array([t.coef.grad(eps) for t in lin], dtype=float).reshape(len(lin), n_eps)
    gK = gK * g00[:, None]
    Klin = np.einsum("q,qij->ij", cs, Ks) if lin else np.zeros((N, N))
    rows, ptr, idx, val, cq, gq = quad
    if M_obs is None:
        Cobs, Gam, Vd = np.zeros((0, N)), np.zeros((N, 0)), np.zeros((n_steps + 1, 0))
    else:
        Cobs = M_obs.toarray() if sp.issparse(M_obs) else np.asarray(M_obs)
        Gam = -system.lam_jacobian()
        Vd = np.asarray(V, dtype=float)
    C = Cobs.shape[0]
    if guess is None:
        start = np.zeros((n_steps + 1, N + C))
    else:
        start = np.concatenate([guess.Theta[:, :, 0], guess.lam.reshape(n_steps + 1, C)], 1)
    Th, lam, dTh, dlam, nits, failed, status, rnorm, LUs, pivs = _kernels.march_p1(
        Mdt, Klin, Ks, gK, rows, ptr, idx, val, cq, gq, F, dF, Cobs, Gam, Vd,
        np.ascontiguousarray(Theta0[:, 0]), start, guess is not None,
        tol, maxiter, bool(sens), bool(keep), *steps,
    )  # fmt: skip
    label = linear.plan.label
    if failed != -1:
        return _failed_trajectory(
            system, times, failed, status, rnorm, maxiter, Th[:, :, None], lam, nits, label
        )
    adjoint = None
    if keep:

        def adjoint(g):  # g: (n_t, N + C) = dz/d(Theta_t, lam_t)
            with np.errstate(all="ignore"):
                return _kernels.adjoint_p1(
                    LUs,
                    pivs,
                    Th,
                    Mdt,
                    Ks,
                    gK,
                    rows,
                    ptr,
                    idx,
                    val,
                    gq,
                    dF,
                    np.ascontiguousarray(g),
                    *steps,
                )

    return Trajectory(
        times,
        Th[:, :, None],
        lam,
        dTh[:, :, None, :] if sens else None,
        dlam if sens and M_obs is not None else None,
        True,
        "converged at every step",
        None,
        nits,
        label,
        [],
        adjoint,
    )
