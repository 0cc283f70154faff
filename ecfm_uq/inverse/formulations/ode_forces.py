"""The exact-match ECFM of a user's ODE: forces piecewise constant between data times.

For an :class:`~ecfm_uq.inverse.problems.ode.OdeProblem` the constraint force is a
function of time :math:`f(t)` added to the right-hand side on the forced components
:math:`F` (default: the observed ones), constant on each interval between consecutive
data times (one value per interval per forced component; the integrator steps inside an
interval as its tolerance needs, the forces are not tied to its steps):

.. math::

    \\dot y = g(t, y;\\epsilon) + E_F f_k,\\qquad t \\in [t_{k-1}, t_k).

For a given :math:`\\epsilon` the forces are determined by exact match, interval by
interval: Newton on :math:`f_k` until the observed components at :math:`t_k` equal the
data (:math:`H_p y(t_k) = d_{k,p}` over the readings present; the force on a component whose
datum is missing is 0). A datum at :math:`t_0` itself cannot be met by a force over an
interval: it is met by an **initial jump** :math:`y(t_0^+) = y_0(\\epsilon) + E_F g`
(weak-constraint 4D-Var's initial-condition error), counted in the objective as the force
:math:`g/\\Delta t_1` spread over the first interval, i.e. :math:`|g|^2/\\Delta t_1`.

The estimate minimizes the size of the force function,

.. math::

    \\int |f(t)|^2\\,dt = \\sum_k \\Delta t_k |f_k|^2\\;(+\\,|g|^2/\\Delta t_1),

which does not depend on how densely the data are sampled: a least-squares problem in
:math:`\\epsilon` with residual :math:`\\sqrt{\\Delta t_k} f_k(\\epsilon)`, whose Jacobian
is the implicit derivative of the exact-match conditions, with the forward sensitivities
:math:`\\Phi_y, \\Phi_\\epsilon, \\Phi_f` of each interval's end state to its start state,
the parameters and its force:

.. math::

    \\frac{df_k}{d\\epsilon} = -(H_p\\Phi_f)^{-1} H_p\\Big(\\Phi_y\\frac{dy_{k-1}}{d\\epsilon}
    + \\Phi_\\epsilon\\Big),\\qquad
    \\frac{dy_k}{d\\epsilon} = \\Phi_y\\frac{dy_{k-1}}{d\\epsilon} + \\Phi_\\epsilon
    + \\Phi_f\\frac{df_k}{d\\epsilon},

and alike in the data :math:`d` (the right-hand side gains the reading itself).

With ``sigma``: to first order the forces are linear in the data noise, :math:`\\delta f
= T\\,\\delta d` with :math:`T = \\partial f/\\partial d + \\partial f/\\partial\\epsilon\\,
d\\hat\\epsilon/dd` (:math:`d\\hat\\epsilon/dd = -J^+\\,\\partial r/\\partial d`, Gauss-Newton),
so their covariance is :math:`T\\Sigma T^T`. The verdict is the chi-squared test of the
forces in that covariance, :math:`f^T(T\\Sigma T^T)^+f \\sim \\chi^2_{\\text{rank}}` (rank:
forces minus parameters), as the exact-match ECFM of a steady problem tests the forces'
effect on the data against the noise. Where: the integrated force of each component,
:math:`\\sum_{k\\in w}\\Delta t_k f_{kj}` (the state change the model lacks), over windows
:math:`w` of 1, 2, 4, ... consecutive intervals (starts half a window apart), and the
initial jump, each with its z-score in the same covariance, compared with the Bonferroni
bound :math:`\\Phi^{-1}(1 - \\alpha/(2M))` over the ``M`` windows tested: the component
and time span of the significant windows that contain no smaller significant one
(touching ones merged, with their largest z) are named (``extra["significant_forces"]``). Single intervals lose power as the sampling
gets denser (a month's force is small against the noise); their sums do not.
"""

from __future__ import annotations

import numpy as np
from scipy import special, stats

from ..._validation import as_finite_array
from ...errors import ConvergenceError
from ..core.details import OdeEcfmDetails
from ..core.fitter import Outcome
from ..core.result import Uncertainty
from ..core.series import ForceSeries, OdeTrajectory
from ..problems.force_bases import check_force_basis
from ..problems.noise_model import NoiseModel
from ..problems.ode import solve_with_sensitivities
from ..statistics.uncertainty import estimate_uncertainty, least_squares_jacobian
from ..statistics.verdict import decide, no_test
from .ode_basis import MAX_NEWTON, fit_forces, fit_ode_basis

__all__ = ["ExactForces", "fit_ode_ecfm"]


class ExactForces:
    """The exact-match forces of an :class:`OdeProblem` as functions of ``eps``.

    Parameters
    ----------
    problem : OdeProblem
        Checked (:meth:`~ecfm_uq.inverse.problems.ode.OdeProblem.check`).
    forced : (m,) ints
        The forced state components, one per observed column (force ``j`` meets the
        readings of column ``j``).
    """

    def __init__(self, problem, forced):
        self.problem = problem
        self.F = np.asarray(forced, dtype=int)
        t, t0 = problem.t, problem.t0
        self.jump = bool(t[0] == t0)
        self.ends = np.arange(1, t.size) if self.jump else np.arange(t.size)
        self.starts = t[:-1] if self.jump else np.r_[t0, t[:-1]]
        self.dt = t[self.ends] - self.starts
        self.m = self.F.size
        self.K = self.ends.size
        mask = problem.mask
        # index of each reading present in the readings vector (time-major)
        self.where = np.full(mask.shape, -1)
        self.where[mask] = np.arange(mask.sum())
        self.warm = np.zeros((self.K, self.m))
        # the last solve's eps and forces' derivatives in eps: the next solve's first
        # Newton guess is their linear prediction (one solve per interval where the
        # prediction already meets the data)
        self.warm_eps = None
        self.warm_slope = None
        self.jump_weight = 1.0 / np.sqrt(self.dt[0]) if self.jump and self.K else 1.0

    @property
    def n_residual(self):
        return (self.K + int(self.jump)) * self.m

    def _match(self, i, y, Y_eps, Y_d, with_data):
        """The observed rows present at datum ``i`` and their data-selection matrix."""
        H = self.problem.H()
        present = self.problem.mask[i]
        Hp = H[present]
        cols = np.flatnonzero(present)
        E = None
        if with_data:
            E = np.zeros((cols.size, Y_d.shape[1]))
            E[np.arange(cols.size), self.where[i, cols]] = 1.0
        return Hp, cols, E

    def solve(self, eps, *, with_data=False, dense=False):
        """The forces at ``eps`` and their derivatives.

        Returns
        -------
        dict
            ``forces`` (K, m), ``jump`` (m,) or None, ``r`` (residual), ``J`` (dr/deps),
            ``R_d`` (dr/dd, with ``with_data``), ``segments`` (dense outputs, ``dense``).
        """
        pb = self.problem
        n, p = pb.n_state, eps.size
        nd = pb.n_data
        y = pb.initial_state(eps).astype(float)
        Y_eps = pb.initial_sensitivity(eps)
        Y_d = np.zeros((n, nd)) if with_data else None
        m = self.m
        r = np.zeros(self.n_residual)
        J = np.zeros((self.n_residual, p))
        R_d = np.zeros((self.n_residual, nd)) if with_data else None
        forces = np.zeros((self.K, m))
        guess = self.warm.copy()
        if self.warm_eps is not None and self.warm_eps.shape == eps.shape:
            guess += (self.warm_slope @ (eps - self.warm_eps)).reshape(self.K, m)
        slope = np.zeros((self.K * m, p))
        jump = None
        row = 0
        if self.jump:
            Hp, cols, E = self._match(0, y, Y_eps, Y_d, with_data)
            jump = np.zeros(m)
            if cols.size:
                EF = np.zeros((n, cols.size))
                EF[self.F[cols], np.arange(cols.size)] = 1.0
                A = Hp @ EF
                g = np.linalg.solve(A, d_at(pb, 0, cols) - Hp @ y)
                dg_eps = -np.linalg.solve(A, Hp @ Y_eps)
                y = y + EF @ g
                Y_eps = Y_eps + EF @ dg_eps
                jump[cols] = g
                w = self.jump_weight
                r[row + cols] = w * g
                J[row + cols] = w * dg_eps
                if with_data:
                    dg_d = np.linalg.solve(A, E - Hp @ Y_d)
                    Y_d = Y_d + EF @ dg_d
                    R_d[row + cols] = w * dg_d
            row += m
        segments = []
        for k in range(self.K):
            i = self.ends[k]
            span = (self.starts[k], pb.t[i])
            Hp, cols, E = self._match(i, y, Y_eps, Y_d, with_data)
            q = cols.size
            EF = np.zeros((n, q))
            EF[self.F[cols], np.arange(q)] = 1.0
            S0 = np.hstack((np.eye(n), np.zeros((n, p + q))))
            T_eps = np.hstack((np.zeros((p, n)), np.eye(p), np.zeros((p, q))))
            G = np.hstack((np.zeros((n, n + p)), EF))
            f = guess[k, cols].copy()
            target = d_at(pb, i, cols)
            scale = max(1.0, np.max(np.abs(target))) if q else 1.0
            # the last Newton update is applied linearly (exact to O(|c|^2)) once the
            # mismatch c is at the integrator's tolerance: no solve for it, and the
            # sensitivities at the previous force are as accurate as the solve
            accept = 10 * (pb.rtol * scale + np.max(pb.atol))
            for _ in range(MAX_NEWTON):
                sol, Yb, Sb = solve_with_sensitivities(
                    pb, eps, span, y, S0, T_eps, G, force=EF @ f, dense=dense,
                    t_eval=[span[1]],
                )  # fmt: skip
                yb, Sb = Yb[-1], Sb[-1]
                Phi_y, Phi_e, Phi_f = Sb[:, :n], Sb[:, n : n + p], Sb[:, n + p :]
                if q == 0:
                    break
                c = Hp @ yb - target
                B = Hp @ Phi_f
                try:
                    step = np.linalg.solve(B, c)
                except np.linalg.LinAlgError as e:
                    raise ConvergenceError(
                        f"the forces on interval [{span[0]:g}, {span[1]:g}] do not move the "
                        f"observed components at eps={eps.tolist()} (singular H dy/df): {e}"
                    ) from e
                f = f - step
                yb = yb - Phi_f @ step
                if np.max(np.abs(c)) <= accept:
                    break
            else:
                raise ConvergenceError(
                    f"Newton on the force of interval [{span[0]:g}, {span[1]:g}] did not "
                    f"meet the data in {MAX_NEWTON} iterations at eps={eps.tolist()}"
                )
            if not np.all(np.isfinite(yb)):
                raise ConvergenceError(f"non-finite state at t={span[1]:g}, eps={eps.tolist()}")
            if dense:
                segments.append((span[0], _StateOnly(sol.sol, n)))
            W_eps = Phi_y @ Y_eps + Phi_e
            w = np.sqrt(self.dt[k])
            if q:
                B = Hp @ Phi_f
                df_eps = -np.linalg.solve(B, Hp @ W_eps)
                Y_eps = W_eps + Phi_f @ df_eps
                J[row + cols] = w * df_eps
                r[row + cols] = w * f
                forces[k, cols] = f
                slope[k * m + cols] = df_eps
            else:
                Y_eps = W_eps
            if with_data:
                W_d = Phi_y @ Y_d
                if q:
                    df_d = np.linalg.solve(B, E - Hp @ W_d)
                    Y_d = W_d + Phi_f @ df_d
                    R_d[row + cols] = w * df_d
                else:
                    Y_d = W_d
            y = yb
            row += m
        # kept only from a complete solve (a failed one leaves the last good guess)
        self.warm, self.warm_eps, self.warm_slope = forces.copy(), eps.copy(), slope
        return {"forces": forces, "jump": jump, "r": r, "J": J, "R_d": R_d,
                "segments": segments}  # fmt: skip


class _StateOnly:
    """The state part of an augmented solve's dense output."""

    def __init__(self, sol, n):
        self.sol, self.n = sol, n

    def __call__(self, times):
        return self.sol(times)[: self.n]


def d_at(problem, i, cols):
    """The readings of datum ``i`` in columns ``cols``."""
    return problem.v[i, cols]


def forced_components(problem):
    """The forced state components, one per observed column: ``problem.forced``, or the
    observed components themselves."""
    n_obs = problem.v.shape[1]
    if problem.forced is not None:
        F = np.asarray(problem.forced)
    elif problem.observe is None:
        F = np.arange(problem.n_state)
    elif problem.observe.ndim == 1:
        F = problem.observe
    else:
        raise ValueError(
            "formulation='ecfm' with `observe` as a matrix needs `forced`, the state "
            f"component each of the {n_obs} observed combinations drives (one per column "
            "of `data`): OdeProblem(..., forced=[...])"
        )
    if F.shape != (n_obs,) or F.dtype.kind not in "iu":
        raise ValueError(
            f"`forced` must list {n_obs} state indices (one per column of `data`), got {F!r}"
        )
    if F.min() < 0 or F.max() >= problem.n_state or np.unique(F).size != F.size:
        raise ValueError(f"`forced` must hold distinct indices in [0, {problem.n_state})")
    return F


def _covariance(sigma, n):
    """The data covariance (n, n) of a checked ``sigma`` (a number or a NoiseModel)."""
    if isinstance(sigma, NoiseModel):
        if sigma.kind == "covariance":
            return sigma.chol @ sigma.chol.T
        return np.diag(np.broadcast_to(np.asarray(sigma.scale, dtype=float) ** 2, (n,)))
    return float(sigma) ** 2 * np.eye(n)


def fit_ode_ecfm(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of an :class:`OdeProblem`, ``formulation="ecfm"``.

    ``options["force_basis"]``: ``"constant"`` (the default, this module's forces) or
    ``"linear"`` / ``{"rbf": width}`` (:func:`.ode_basis.fit_ode_basis`)."""
    if s.method not in ("auto", "least-squares", "trf"):
        raise ValueError(
            f"unknown `method` {s.method!r} for the ECFM of an OdeProblem; choose "
            "'least-squares' (trust-region reflective, the default)"
        )
    options = s.take({"polish": True, "x_scale": "jac", "ftol": 1e-15, "xtol": 1e-15,
                      "gtol": 1e-15, "force_basis": "constant"})  # fmt: skip
    basis = options.pop("force_basis")
    kind = check_force_basis(basis)[0]
    eps0 = problem.check(as_finite_array("eps0", eps0, ndim=1))
    if kind != "constant":  # a basis coupling the intervals: all forces in one solve
        return fit_ode_basis(problem, eps0, forced_components(problem), basis, s, options)
    forces = ExactForces(problem, forced_components(problem))
    out, common = fit_forces(problem, forces, eps0, s, options)
    if out.payload is None:
        return Outcome(eps=out.x, loss=np.inf, verdict=no_test(out.message),
                       extra=OdeEcfmDetails(n_missing=problem.n_missing), **common)  # fmt: skip
    final = forces.solve(out.x, with_data=s.sigma is not None, dense=True)
    series, unc, verdict, extra = _statistics(problem, forces, final, out.x, s)
    seg = final["segments"]
    ts = np.concatenate([sg[1].sol.ts for sg in seg]) if seg else np.array([problem.t0])
    ts = np.unique(ts)
    traj = OdeTrajectory(ts, np.zeros((ts.size, problem.n_state)), problem.state_names,
                         tuple(seg))  # fmt: skip
    traj = OdeTrajectory(ts, traj(ts), problem.state_names, tuple(seg))
    return Outcome(
        eps=out.x, loss=out.loss, njev=out.nit, state=traj, forces=series, uncertainty=unc,
        verdict=verdict, extra=OdeEcfmDetails(n_missing=problem.n_missing, **extra), **common,
    )  # fmt: skip


def _statistics(problem, forces, final, eps, s):
    """The force series, the uncertainty, the verdict and the extras at the estimate."""
    names = [problem.state_names[j] for j in forces.F]
    t = problem.t
    intervals = np.column_stack((forces.starts, t[forces.ends]))
    free = np.r_[problem.mask[0] if forces.jump else np.zeros(0, bool),
                 problem.mask[forces.ends].ravel()]  # fmt: skip
    kw = dict(times=forces.starts.copy(), intervals=intervals, values=final["forces"],
              names=names, jump=final["jump"])  # fmt: skip
    if s.sigma is None:
        why = (
            "uncertainty not computed: the exact-match ECFM's estimate is a function of the "
            "data; pass `sigma` for its covariance"
        )
        verdict = decide("force size", None, None, [
            f"no noise level: the forces' integral of squares is "
            f"{float(final['r'] @ final['r']):.3g}; pass `sigma` for a chi-squared test of "
            "the forces"], explained=None)  # fmt: skip
        return ForceSeries(**kw), Uncertainty.failed(why), verdict, {}
    J, R_d = final["J"], final["R_d"]
    Sigma = _covariance(s.sigma, problem.n_data)
    try:
        Jp = least_squares_jacobian(J, problem.names)
    except ValueError as e:
        return ForceSeries(**kw), Uncertainty.failed(f"uncertainty not computed: {e}"), \
            no_test(str(e)), {}  # fmt: skip
    D = -Jp @ R_d  # d eps_hat / d data (Gauss-Newton)
    unc = estimate_uncertainty(None, eps, None, Sigma, "known", deps_dv=D)
    # forces (scaled residual) as a linear function of the data noise
    Tr = R_d + J @ D
    w = np.repeat(np.r_[[forces.jump_weight] if forces.jump else [], np.sqrt(forces.dt)],
                  forces.m)  # fmt: skip
    rows = np.flatnonzero(free)
    L = np.linalg.cholesky(Sigma)
    Tw = Tr[rows] @ L
    cov_r = Tw @ Tw.T
    se_r = np.zeros(free.size)
    se_r[rows] = np.sqrt(np.maximum(np.diag(cov_r), 0.0))
    se = se_r / w
    f_r = final["r"][rows]
    U, sv, _ = np.linalg.svd(Tw, full_matrices=False)
    keep = sv > 1e-8 * sv[0]
    dof = int(keep.sum())
    z = (U[:, keep].T @ f_r) / sv[keep]
    chi2 = float(z @ z)
    p_value = float(stats.chi2.sf(chi2, dof))
    m = forces.m
    off = m if forces.jump else 0
    stderr = se[off:].reshape(forces.K, m)
    kw.update(stderr=stderr, jump_stderr=se[:off] if forces.jump else None)
    series = ForceSeries(**kw)
    hits, bound = _significant_windows(problem, forces, names, intervals, rows, f_r, Tw,
                                       s.alpha)  # fmt: skip
    where = "no force window passes the Bonferroni bound"
    if hits:
        worst = sorted(hits, key=lambda h: -abs(h[2]))[:3]
        where = f"significant forces (|z| > {bound:.2f}, Bonferroni over windows): " + ", ".join(
            f"{n} on [{a:g}, {b:g}] (z = {zz:.1f})" for n, (a, b), zz in worst
        )
    parts = [f"chi2 of the forces = {chi2:.3g} on {dof} degrees of freedom, p = {p_value:.3g} "
             f"{'>=' if p_value >= s.alpha else '<'} alpha = {s.alpha:g}; {where}"]  # fmt: skip
    verdict = decide("chi2 of forces", p_value, s.alpha, parts, statistic=chi2,
                     details={"chi2": chi2, "dof": dof, "bonferroni_z": bound})  # fmt: skip
    extra = {"significant_forces": hits, "force_cov": cov_r / np.outer(w[rows], w[rows])}
    return series, unc, verdict, extra


def _significant_windows(problem, forces, names, intervals, rows, f_r, Tw, alpha):
    """Where the forces are significant: the integrated force :math:`\\sum_{k\\in w}
    \\Delta t_k f_{kj}` of each component over windows of 1, 2, 4, ... consecutive
    intervals (starts half a window apart; and the initial jump), its z-score against its
    standard deviation from the data noise, Bonferroni over every window tested. A window
    with no noise of its own (a force the fit fixes, e.g. the first interval's by a fitted
    initial state) gets no z-score. Returned: the significant windows that contain no
    smaller significant window of the same component, touching ones merged (with their
    largest z), ``(name, (start, end), z)``, and the bound."""
    m, K = forces.m, forces.K
    off = m if forces.jump else 0
    pos = np.full(off + K * m, -1)
    pos[rows] = np.arange(rows.size)
    sq = np.sqrt(forces.dt)
    coef, where = [], []
    for j in range(m):
        if forces.jump and pos[j] >= 0:
            c = np.zeros(rows.size)
            c[pos[j]] = 1.0
            coef.append(c)
            where.append((j, problem.t0, problem.t0))
        L = 1
        while L <= K:
            for a in range(0, K - L + 1, max(1, L // 2)):
                c = np.zeros(rows.size)
                for k in range(a, a + L):
                    if pos[off + k * m + j] >= 0:
                        c[pos[off + k * m + j]] = sq[k]
                coef.append(c)
                where.append((j, intervals[a, 0], intervals[a + L - 1, 1]))
            L *= 2
    C = np.array(coef)
    g = C @ f_r
    sd = np.linalg.norm(C @ Tw, axis=1)
    noisy = sd > 1e-6 * np.max(sd, initial=0.0)
    z = np.zeros(g.size)
    z[noisy] = g[noisy] / sd[noisy]
    bound = float(special.ndtri(1 - alpha / (2 * max(int(noisy.sum()), 1))))
    sig = [(where[i], float(z[i])) for i in np.flatnonzero(np.abs(z) > bound)]
    minimal = sorted(
        (j, a, b, zz) for (j, a, b), zz in sig
        if not any(jj == j and a <= aa and bb <= b and (aa, bb) != (a, b)
                   for (jj, aa, bb), _ in sig)
    )  # fmt: skip
    hits = []  # touching or overlapping minimal windows of a component merged, largest |z|
    for j, a, b, zz in minimal:
        if hits and hits[-1][0] == names[j] and a <= hits[-1][1][1]:
            name, (a0, b0), z0 = hits[-1]
            hits[-1] = (name, (a0, max(b0, float(b))), z0 if abs(z0) >= abs(zz) else zz)
        else:
            hits.append((names[j], (float(a), float(b)), zz))
    return hits, bound
