"""The compiled marches (:mod:`._kernels`): ``P = 1`` dense and ``P > 1`` node-preconditioned."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .linear import (
    COMPILED_MARCH_MAX_N,
    nodal_march_eligible,
)
from .terms import LinearTerm, LoadTerm, QuadraticTerm
from .trajectory import Trajectory

# the P > 1 march's chord iteration hands a step to Newton-Krylov when its residual falls
# by less than this factor per iteration (<= 0: Newton-Krylov throughout)
_CHORD_RATE = 0.25
_COMPILED = {"disabled": False}


def _compiled_kernels():
    """The compiled march's module, or ``None`` where it cannot work.

    The kernels reach LAPACK through numba's own binding (``numba.np.linalg``), which is
    numba-internal: if a numba release moves it, every march takes the generic Python
    path (same results, slower) instead of failing.
    """
    if _COMPILED["disabled"]:
        return None
    try:
        from . import _kernels
    except (ImportError, AttributeError):
        _COMPILED["disabled"] = True
        return None
    return _kernels


def _compiled_march(
    linear, system, eps, Theta0, dt, n_steps, t0, M_obs, V, sens, tol, maxiter, keep, guess
):
    """March with a compiled kernel when the system qualifies, else ``None``.

    ``P = 1`` with the dense solver, at most one quadratic term and ``N`` at most 128
    (its tensor kept as compressed rows of the nonzeros): :func:`_kernels.march_p1`.
    ``P > 1`` with the node-preconditioned Krylov solver that
    :func:`.linear.choose_solver` picks for such marches (no data constraint, no kept
    factors, :func:`.linear.nodal_march_eligible`): :func:`_kernels.march_sg`.
    """
    N, P = system.shape
    quads = [t for t in system.terms if isinstance(t, QuadraticTerm)]
    if len(quads) > 1 or N > COMPILED_MARCH_MAX_N:
        return None
    if P == 1 and linear.name != "dense":
        return None
    if P > 1 and not (
        linear.name == "gmres"
        and linear.preconditioner_kind() == "nodal"
        and M_obs is None
        and not keep
        and nodal_march_eligible(system)
    ):
        return None
    _kernels = _compiled_kernels()
    if _kernels is None:
        return None
    lin = [t for t in system.terms if isinstance(t, LinearTerm)]
    loads = [t for t in system.terms if isinstance(t, LoadTerm)]
    n_eps = system.n_eps
    times = t0 + dt * np.arange(n_steps + 1)
    if "_compiled_Ks" not in system.__dict__:  # fixed operators: stacked once per system
        dense = [t.K.toarray() if t.sparse else t.K for t in lin]
        system._compiled_Ks = np.array(dense).reshape(len(lin), N, N)
    Ks = system._compiled_Ks
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
    quad = (rows, ptr, idx, val, float(cq), gq)
    args = (system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep, guess)
    from numba.core.errors import NumbaError

    try:
        with np.errstate(all="ignore"):
            if P == 1:
                F1, dF1 = np.ascontiguousarray(F[:, :, 0]), np.ascontiguousarray(dF[:, :, 0])
                return _march_p1(_kernels, linear, *args, lin, Ks, quad, F1, dF1, Mdt)
            return _march_sg(_kernels, linear, *args, lin, Ks, quad, F, dF, Mdt)
    except NumbaError:  # the kernel does not compile with this numba: use the generic march
        _COMPILED["disabled"] = True
        return None


def _failed_trajectory(system, times, failed, rnorm, maxiter, Theta, lam, nits, label, its=()):
    """The trajectory up to a compiled march's failed step, with the reason."""
    k = failed + 1
    where = f"{system.name}: Newton failed at step {k} (t={times[k]:.6g})"
    if rnorm == -1.0:
        msg = f"{where}: the step Jacobian is singular"
    elif rnorm == -2.0:
        msg = f"{where}: GMRES did not reach its tolerance (see SolverOptions.maxiter)"
    else:
        msg = f"{where} with ||R||={rnorm:.3e}: no convergence in {maxiter} iterations"
    return Trajectory(
        times[:k], Theta[:k], lam[:k], None, None, False, msg, k, nits[:k], label, list(its[:k])
    )


def _march_sg(_kernels, linear, system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep,
              guess, lin, Ks, quad, F, dF, Mdt):  # fmt: skip
    """The ``P > 1`` compiled march (:func:`_kernels.march_sg`)."""
    N, P = system.shape
    n_eps = system.n_eps
    nodes = system.gauss_nodes()
    if "_compiled_nodal" not in system.__dict__:  # node factors of the fixed couplings
        Gs = np.array([t.G for t in lin]).reshape(len(lin), P, P)
        gnode = np.array([nodes.coupling_values(G) for G in Gs]).reshape(len(lin), P)
        E3m = np.zeros((P, P * P))
        quads = [t for t in system.terms if isinstance(t, QuadraticTerm)]
        if quads:  # E3[b, c, l] as row c, column b P + l
            E3m = np.ascontiguousarray(quads[0]._E3.transpose(1, 0, 2).reshape(P, P * P))
        system._compiled_nodal = (Gs, gnode, nodes.coupling_values(system.E2), E3m)
    Gs, gnode, mnode, E3m = system._compiled_nodal
    cs = np.array([t.coef.value(eps) for t in lin], dtype=float).reshape(len(lin))
    gK = np.array([t.coef.grad(eps) for t in lin], dtype=float).reshape(len(lin), n_eps)
    rows, ptr, idx, val, cq, gq = quad
    start = np.zeros((1, N, P)) if guess is None else np.ascontiguousarray(guess.Theta)
    opts = linear.options
    Th, dTh, nits, kits, failed, rnorm = _kernels.march_sg(
        np.ascontiguousarray(Mdt), np.ascontiguousarray(system.E2), Ks, cs, Gs, gK,
        rows, ptr, idx, val, cq, gq, E3m, F, dF,
        np.ascontiguousarray(nodes.Phi.T), nodes.to_nodes, nodes.from_nodes, mnode, gnode,
        np.ascontiguousarray(Theta0), start, guess is not None, tol, maxiter, bool(sens),
        opts.rtol, opts.restart, opts.maxiter, _CHORD_RATE,
    )  # fmt: skip
    label = "gmres+nodal (compiled)"
    lam = np.zeros((len(times), 0))
    if failed != -1:
        return _failed_trajectory(system, times, failed, rnorm, maxiter, Th, lam, nits, label, kits)
    return Trajectory(
        times, Th, lam, dTh if sens else None, None, True, "converged at every step", None,
        nits, label, [int(k) for k in kits],
    )  # fmt: skip


def _march_p1(_kernels, linear, system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep,
              guess, lin, Ks, quad, F, dF, Mdt):  # fmt: skip
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
    Th, lam, dTh, dlam, nits, failed, rnorm, LUs, pivs = _kernels.march_p1(
        Mdt, Klin, Ks, gK, rows, ptr, idx, val, cq, gq, F, dF, Cobs, Gam, Vd,
        np.ascontiguousarray(Theta0[:, 0]), start, guess is not None,
        tol, maxiter, bool(sens), bool(keep),
    )  # fmt: skip
    label = "dense (compiled)"
    if failed != -1:
        return _failed_trajectory(
            system, times, failed, rnorm, maxiter, Th[:, :, None], lam, nits, label
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
