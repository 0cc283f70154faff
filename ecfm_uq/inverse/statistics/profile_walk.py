"""The machinery of one profile: the inner re-optimizations and the walk along a parameter.

:class:`Profiler` minimizes the likelihood over the other parameters at a fixed value of one
(Levenberg-Marquardt on the residual of a Gaussian likelihood, L-BFGS-B on its gradient
otherwise); :func:`walk` steps out from the estimate to the threshold's crossing
(:func:`crossing`, Brent), and :func:`beyond` searches the rest of the range to a finite
bound for a return below the threshold. :mod:`ecfm_uq.inverse.statistics.profile` assembles
them into profiles, intervals and tests.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from ...errors import ConvergenceError, ModelEvaluationError
from ..core.convergence import at_bound as bounds_hit
from ..core.finite_differences import fd_gradient

__all__ = ["MODEL_FAILURES", "Profiler", "beyond", "bound_touches", "profile_concerns", "walk"]

MODEL_FAILURES = (ConvergenceError, ModelEvaluationError, np.linalg.LinAlgError)
#: the likelihood increase standing in for "the model fails here"
WALL = 1e12
# central-difference step of a value-only likelihood, in units of the parameters' scale
_FD_STEP = 1e-5


class Profiler:
    """Minimizes the likelihood over the other parameters at fixed :math:`\\epsilon_i`."""

    def __init__(self, like, eps_hat, ell_hat, scale, bounds):
        self.like, self.eps_hat, self.ell_hat = like, eps_hat, ell_hat
        self.scale, self.bounds = scale, bounds
        self.nfev = 0
        self.visited = []  # optima of the inner problems, reused as starting points
        # (fixed indices, values) where no inner optimizer run reported convergence:
        # evidence against the profile there (ProfileSummary.trusted)
        self.unconverged = []
        exact = like.exact_gradient
        self.by_differences = not exact and like.value_only is not None
        self.inner_options = {
            "ftol": 1e-15 if exact else 1e-12,
            "gtol": 1e-9 if exact else 1e-6,
            "maxiter": 500,
        }

    def at(self, fixed, values, start):
        """:math:`\\ell` minimized over the free parameters with ``eps[fixed] = values``.

        Returns (delta, eps) with the re-optimized parameters; raises the model's error
        where it cannot be solved.
        """
        fixed = np.atleast_1d(fixed)
        free = np.setdiff1d(np.arange(self.like.n_eps), fixed)
        eps = np.array(start, dtype=float)
        eps[fixed] = values
        if free.size == 0:
            self.nfev += 1
            return self.like(eps)[0] - self.ell_hat, eps
        s = self.scale[free]
        x0 = (eps[free] - self.eps_hat[free]) / s

        def point(x):
            e = eps.copy()
            e[free] = self.eps_hat[free] + s * x
            return e

        def fun(x):
            self.nfev += 1
            try:
                if self.by_differences:
                    # a value-only likelihood: central differences in the free parameters
                    # alone (in units of their scale), not the full gradient
                    def value(y):
                        return self.like.value(point(y))

                    return value(x), fd_gradient(value, x, _FD_STEP)
                val, g = self.like(point(x))
            except MODEL_FAILURES:
                # where the model cannot be solved: a wall the line search backs off from
                return self.ell_hat + WALL, np.zeros(free.size)
            if np.isnan(val) or val == np.inf:  # overflowed: a failed point too
                return self.ell_hat + WALL, np.zeros(free.size)
            return val, g[free] * s

        bnds = [
            ((lo - self.eps_hat[j]) / self.scale[j], (hi - self.eps_hat[j]) / self.scale[j])
            for j, (lo, hi) in zip(free, (self.bounds[j] for j in free), strict=True)
        ]
        best = None
        # the inner problem need not be convex (a flat direction can hide a lower valley):
        # besides the warm start, start from the visited optimum nearest in the fixed
        # coordinates (e.g. the other parameters' profiles); the estimate's values last
        starts = [x0]
        if self.visited:
            far = np.array(
                [np.max(np.abs(v[fixed] - eps[fixed]) / self.scale[fixed]) for v in self.visited]
            )
            near = self.visited[int(np.argmin(far))]
            x1 = (near[free] - self.eps_hat[free]) / s
            if np.max(np.abs(x1 - x0)) > 1e-3:
                starts.append(x1)
        for k, x_start in enumerate([*starts, np.zeros(free.size)]):
            if k == len(starts) and best is not None and best.success:
                break
            if self.like.residual is not None:
                res = self._least_squares(point, free, s, x_start, bnds)
            else:
                res = optimize.minimize(
                    fun, x_start, jac=True, method="L-BFGS-B", bounds=bnds,
                    options=self.inner_options,
                )  # fmt: skip
            if best is None or res.fun < best.fun:
                best = res
        res = best
        if res.fun >= self.ell_hat + 0.5 * WALL:
            raise ConvergenceError(
                f"the model cannot be solved anywhere the profile searched at eps{fixed.tolist()}"
                f"={np.round(values, 6).tolist()}"
            )
        eps[free] = self.eps_hat[free] + s * res.x
        if not res.success:
            self.unconverged.append((tuple(fixed.tolist()), tuple(np.atleast_1d(values))))
        self.visited.append(eps.copy())
        return float(res.fun) - self.ell_hat, eps

    def nuisance_along(self, eps):
        """(k, 2) array of ``like.nuisance`` (the re-estimated nuisance and the variance
        term) at each row of ``eps``, NaN where the model cannot be solved; None for a
        likelihood without one."""
        if self.like.nuisance is None:
            return None
        out = np.full((len(eps), 2), np.nan)
        for k, e in enumerate(eps):
            try:
                out[k] = self.like.nuisance(e)
            except MODEL_FAILURES:
                pass
        return out

    def _least_squares(self, point, free, s, x_start, bnds):
        """The inner problem of a Gaussian likelihood by trust-region least squares on its
        residual (the Jacobian's free columns only: a differenced model pays for those)."""
        like = self.like
        n = like.n_data

        def fun(x):
            self.nfev += 1
            try:
                r = like.residual(point(x))
            except MODEL_FAILURES:
                return np.full(n, np.inf)  # the trust region shrinks away from it
            return r

        def jac(x):
            return like.residual_jacobian(point(x), free) * s

        lb = np.array([b[0] for b in bnds], dtype=float)
        ub = np.array([b[1] for b in bnds], dtype=float)
        try:
            x, rss, ok = _levenberg_marquardt(fun, jac, x_start, lb, ub)
        except MODEL_FAILURES:
            ok, x, rss = False, x_start, np.inf
        if not np.isfinite(rss):
            return optimize.OptimizeResult(x=x_start, fun=self.ell_hat + WALL, success=False)
        return optimize.OptimizeResult(x=x, fun=float(like.of_rss(rss)), success=ok)


def _sum_of_squares(r):
    """:math:`r^Tr`, infinite where it overflows or ``r`` is not finite: at extreme
    parameter values overflow is the expected answer (a failed point, no warning)."""
    with np.errstate(over="ignore", invalid="ignore"):
        S = float(r @ r)
    return S if np.isfinite(S) else np.inf


def _levenberg_marquardt(fun, jac, x0, lb, ub, maxiter=100, rtol=1e-12):
    """Minimize :math:`\\|r(x)\\|^2` over the box [lb, ub] by Levenberg-Marquardt steps
    (Marquardt's scaling by the diagonal of :math:`J^TJ`, steps projected on the box).

    The profiles' inner problems are small (the free parameters, in units of their
    standard errors) and start next to their optimum (warm starts): a few steps, each one
    residual and one Jacobian, where a general trust-region solver spends milliseconds of
    its own per iteration. Converged when the Gauss-Newton step would decrease the sum of
    squares by at most ``rtol`` of it (:math:`g^T(J^TJ)^+g \\le` ``rtol`` :math:`S`, on the
    parameters free of the box), never on the size of a damped step.

    Returns
    -------
    x, rss, converged
    """
    x = np.clip(np.asarray(x0, dtype=float), lb, ub)
    r = fun(x)
    S = _sum_of_squares(r)
    if not np.isfinite(S):
        return x, np.inf, False
    mu = None
    for _ in range(maxiter):
        J = jac(x)
        with np.errstate(over="ignore", invalid="ignore"):
            g, A = J.T @ r, J.T @ J
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(A))):
            return x, S, False  # a Jacobian too large to square: a failed inner fit
        # parameters held at a bound by the gradient do not count in the test
        held = ((x <= lb) & (g > 0)) | ((x >= ub) & (g < 0))
        free = ~held
        if not free.any():
            return x, S, True
        gf = g[free]
        predicted = float(gf @ np.linalg.lstsq(A[np.ix_(free, free)], gf, rcond=None)[0])
        if predicted <= rtol * S or S == 0.0:
            return x, S, True
        d = np.diag(A).copy()
        d[d <= 0] = d.max() if d.max() > 0 else 1.0
        mu = 1e-3 if mu is None else mu  # Marquardt's damping, relative to diag(A)
        while True:
            # the parameters held at a bound stay there: the step is on the others (a step
            # clipped back onto the bound zig-zags along it, one short step at a time)
            step = np.zeros(x.size)
            try:
                Af = A[np.ix_(free, free)] + mu * np.diag(d[free])
                step[free] = np.linalg.solve(Af, -g[free])
            except np.linalg.LinAlgError:
                step = np.full(x.size, np.nan)
            x1 = np.clip(x + step, lb, ub)
            r1 = fun(x1) if np.all(np.isfinite(x1)) else np.full(r.size, np.inf)
            S1 = _sum_of_squares(r1)
            if S1 <= S:
                break
            mu *= 4.0
            if mu > 1e16:  # no decrease along any damped step: round-off
                return x, S, predicted <= 1e3 * rtol * S
        x, r, S = x1, r1, S1
        mu = max(mu / 3.0, 1e-15)
    return x, S, False


def walk(prof, i, direction, threshold, start_step, bound, max_steps):
    """Points of one half-profile and its end: (points, end, reason).

    ``points`` are (t, delta, eps) from the estimate outward.
    """
    t0 = prof.eps_hat[i]
    points, start = [], prof.eps_hat.copy()
    h, t_prev, d_prev = start_step, t0, 0.0
    for _ in range(max_steps):
        t = t0 + direction * (abs(t_prev - t0) + h)
        at_bound = direction * (t - bound) >= 0
        if at_bound:
            t = bound
        try:
            d, eps = prof.at(i, t, start)
        except MODEL_FAILURES as e:
            if h > 1e-6 * start_step:
                h *= 0.25  # approach the region where the model fails more carefully
                continue
            return (
                points,
                direction * np.inf,
                (
                    f"the model cannot be solved at eps[{i}]={t:.6g} ({type(e).__name__}) "
                    "before the profile reaches the threshold"
                ),
            )
        points.append((t, d, eps))
        if d >= threshold:
            return points, crossing(prof, i, t_prev, t, start, threshold), "crossed"
        if at_bound:
            return (
                points,
                bound,
                (
                    f"the profile stays below the threshold up to the bound eps[{i}]={bound:g} "
                    f"(2*delta = {2 * d:.3g} < {2 * threshold:.3g}): the data do not bound "
                    "it on that side"
                ),
            )
        # grow the step where the profile is flat (a quadratic profile needs ~3 steps)
        rise = d - d_prev
        if rise < 0.25 * threshold:
            h *= 2.0
        t_prev, d_prev, start = t, d, eps
    return (
        points,
        direction * np.inf,
        (
            f"the profile of eps[{i}] is still below the threshold at {t_prev:.6g} after "
            f"{max_steps} steps (2*delta = {2 * d_prev:.3g} < {2 * threshold:.3g}): not "
            "identifiable from these data on that side"
        ),
    )


def crossing(prof, i, t_in, t_out, start, threshold):
    """The t between t_in (below threshold) and t_out (above) where delta = threshold."""
    warm = {"eps": start}

    def g(t):
        d, eps = prof.at(i, t, warm["eps"])
        warm["eps"] = eps
        return d - threshold

    xtol = 1e-8 * max(abs(t_out - t_in), 1e-300)
    return optimize.brentq(g, t_in, t_out, xtol=xtol, rtol=1e-12)


def beyond(prof, i, direction, threshold, t_cross, start, bound, n_scan):
    """Search from a crossing to the (finite) bound for a return of the profile below the
    threshold (a second basin, a ridge to the bound). Returns (points, regions).

    The profile is evaluated on ``n_scan`` evenly spaced points; every local minimum of
    those values (the bound included) is refined by a bounded scalar minimization between
    its neighbours, and where the minimum is below the threshold the region's ends are the
    crossings on either side (a region reaching the bound ends there). A basin narrower
    than the grid spacing whose neighbours do not dip is not found.
    """
    ts = t_cross + (bound - t_cross) * np.arange(0, n_scan + 1) / n_scan
    points, values, warm = [(t_cross, threshold, start)], [threshold], start
    for t in ts[1:]:
        try:
            d, warm = prof.at(i, t, warm)
        except MODEL_FAILURES:
            d = np.inf  # the model fails here: not a region
        points.append((t, d, warm))
        values.append(d)
    values = np.array(values)
    regions = []

    def delta(t, near):
        try:
            return prof.at(i, t, near)[0]
        except MODEL_FAILURES:
            return np.inf

    for k in range(1, n_scan + 1):
        last = k == n_scan
        if not (values[k] <= values[k - 1] and (last or values[k] <= values[k + 1])):
            continue
        if regions and direction * (ts[k] - regions[-1][1 if direction > 0 else 0]) <= 0:
            continue  # inside a region found already
        near = points[k][2]
        lo, hi = sorted((ts[k - 1], ts[k] if last else ts[k + 1]))
        m = optimize.minimize_scalar(
            lambda t, near=near: delta(t, near), bounds=(lo, hi), method="bounded",
            options={"xatol": 1e-6 * abs(hi - lo)},
        )  # fmt: skip
        t_min, d_min = (float(m.x), float(m.fun)) if m.fun < values[k] else (ts[k], values[k])
        if last and values[k] <= m.fun:
            t_min, d_min = ts[k], values[k]
        if not d_min < threshold:
            continue
        eps_min = prof.at(i, t_min, near)[1]
        # the grid points bracketing the region: the nearest on either side of t_min
        # that is at or above the threshold (the crossing itself on the inner side)
        j = k
        while j > 0 and (values[j] < threshold or direction * (ts[j] - t_min) >= 0):
            j -= 1
        ends = [_region_end(prof, i, t_min, ts[j], eps_min, threshold)]
        j = k
        while j < n_scan and (values[j] < threshold or direction * (ts[j] - t_min) <= 0):
            j += 1
        if values[j] >= threshold and direction * (ts[j] - t_min) > 0:
            ends.append(_region_end(prof, i, t_min, ts[j], eps_min, threshold))
        else:
            ends.append(bound)  # below the threshold up to the bound: an open end
        regions.append(tuple(sorted(ends)))
    return points[1:], regions


def _region_end(prof, i, t_in, t_out, start, threshold):
    """The crossing between ``t_in`` (below the threshold) and ``t_out`` (at or above it);
    ``t_out`` itself where the two are not bracketed any more (round-off at a crossing
    found before)."""
    try:
        return crossing(prof, i, t_in, t_out, start, threshold)
    except ValueError:
        return t_out


#: bisection steps locating where a re-optimized parameter first reaches its bound beyond
#: an interval's end (the gap between two profile points shrinks 2**-8-fold)
TOUCH_BISECTIONS = 8


def _at_bound(i, t, row, bounds):
    """The (parameter, side) pairs at their bound at a profile point, ``eps[i] = t``
    included (the profiled parameter at its own bound)."""
    row = np.array(row, dtype=float)
    row[i] = t
    return bounds_hit(row, bounds)


def bound_touches(prof, i, pts, ends, bounds):
    """Where a parameter first sits at its bound beyond each end of an interval.

    Outward from each finite end, the first computed profile point at which some parameter
    (the profiled one or a re-optimized one) is at its bound; when the point before it is
    not, the first such ``t`` between the two is located by bisection
    (``TOUCH_BISECTIONS`` inner fits), since the profile rises steeply past it (the
    parameter held at the bound cannot follow a ridge) and the point found first can be far
    above the lowest point of the bound's face. Returns the new points (t, delta, eps).
    """
    new = []
    for direction, end in ((-1, ends[0]), (1, ends[1])):
        if not np.isfinite(end):
            continue
        out = sorted((q for q in pts if direction * (q[0] - end) >= 0),
                     key=lambda q: direction * (q[0] - end))  # fmt: skip
        k = next((k for k, q in enumerate(out) if _at_bound(i, q[0], q[2], bounds)), None)
        if k is None or k == 0:
            continue
        (t_in, _, e_in), t_at = out[k - 1], out[k][0]
        if t_at == t_in:
            continue
        found = None
        for _ in range(TOUCH_BISECTIONS):
            t = 0.5 * (t_in + t_at)
            try:
                d, e = prof.at(i, t, e_in)
            except MODEL_FAILURES:
                break
            if _at_bound(i, t, e, bounds):
                t_at, found = t, (t, d, e)
            else:
                t_in, e_in = t, e
        if found is not None:
            new.append(found)
    return new


#: a fall of the profile on its way out larger than this fraction of the threshold is a
#: non-monotone branch (smaller ones are the inner fits' round-off)
MONOTONE_RTOL = 0.01


#: a change of the variance term (half the log-determinant of the data covariance) inside
#: an interval larger than this fraction of the threshold: the interval rests on the
#: re-estimated nuisance variance
NUISANCE_FRACTION = 0.5


def _nuisance_concerns(i, nuisance, inside, threshold):
    """A nuisance variance (tau >= 0) re-estimated along the profile: at its bound in part
    of the interval, or shaping it through the variance term."""
    if nuisance is None or not inside.any():
        return []
    tau, half_logdet = nuisance[inside, 0], nuisance[inside, 1]
    tau, half_logdet = tau[np.isfinite(tau)], half_logdet[np.isfinite(half_logdet)]
    out = []
    if np.any(tau == 0) and np.any(tau > 0):
        out.append(
            f"the nuisance tau-hat is 0 at part of the interval of eps[{i}] and positive at "
            "another (a nuisance at its bound, a kink in the profile): the chi-squared "
            "threshold does not hold there"
        )
    if np.any(tau > 0) and half_logdet.size:
        span = float(np.max(half_logdet) - np.min(half_logdet))
        if span > NUISANCE_FRACTION * threshold:
            out.append(
                f"the variance term (1/2 log det of the data covariance, tau-hat up to "
                f"{np.max(tau):.3g}) changes by {2 * span:.3g} (in 2*delta) inside the "
                f"interval of eps[{i}], more than {NUISANCE_FRACTION:g} of the threshold: "
                "the interval rests on tau re-estimated from the few error contrasts, and "
                "the chi-squared threshold need not hold"
            )
    return out


def profile_concerns(i, values, delta, eps, main, reasons, regions, threshold, bounds,
                     unconverged=(), calibrated=False, joint=None, nuisance=None):  # fmt: skip
    """The profile's own evidence against the interval of parameter ``i``.

    An interval from the chi-squared (or profile-t) threshold is what it says only where
    the profile is a regular likelihood ratio: both ends crossed, one region, the profile
    rising on the way out, every re-optimized parameter inside its box and every inner fit
    converged. Each failure of these is returned as a sentence; none of them is the
    distance to the delta-method interval (a skewed likelihood is not a failure).

    Parameters
    ----------
    i : int
    values, delta : (k,) ndarray
        The profile's points, increasing in ``values``.
    eps : (k, n_eps) ndarray
        The re-optimized parameters at those points.
    main : (lower, upper)
        The region around the estimate (the walks' two ends).
    reasons : (str, str)
        Why each end is where it is.
    regions : sequence of (lower, upper)
    threshold : float
    bounds : sequence of (lo, hi)
    unconverged : sequence of (fixed, values)
        Inner fits that did not converge (:class:`~.profile_walk.Profiler`).
    calibrated : bool
        The threshold was simulated (:mod:`~.profile_calibration`): a parameter at its
        bound is then no evidence against it.
    joint : float, optional
        The joint confidence region's level of ``delta`` (:math:`\\tfrac12\\chi^2_p`,
        p the number of parameters). Outside the interval, the first profile point on
        each side with a parameter at its bound (the profiled one, or a re-optimized one:
        :func:`bound_touches`) is evidence against the interval when its ``delta`` is
        below this: the bound is then inside the region of parameters the data do not
        exclude, and the chi-squared threshold, which assumes an interior optimum with
        room around it, need not hold (a likelihood ridge running to a bound).
    nuisance : (k, 2) ndarray, optional
        A nuisance variance re-estimated at each point (:meth:`Profiler.nuisance_along`: the
        random-force ECFM's :math:`\\hat\\tau` and half the log-determinant of the data
        covariance). Inside the interval, :math:`\\hat\\tau` at its bound 0 at some points
        and positive at others (a kink), or positive with the variance term changing by
        more than ``NUISANCE_FRACTION`` of ``threshold`` (the interval is then shaped by
        the variance model, whose :math:`\\tau` rests on a few error contrasts), is
        evidence against a chi-squared interval.
    """
    concerns = [
        f"{side} end open" for side, r in zip(("lower", "upper"), reasons, strict=True)
        if not r.startswith("crossed")
    ]  # fmt: skip
    if len(regions) > 1:
        concerns.append(f"{len(regions)} regions below the threshold")
    lo, hi = main
    inside = (values >= lo) & (values <= hi)
    t, d = values[inside], delta[inside]
    if t.size > 2:
        k = int(np.argmin(d))
        fall = max(np.max(np.diff(d[: k + 1]), initial=0.0), np.max(-np.diff(d[k:]), initial=0.0))
        if fall > MONOTONE_RTOL * threshold:
            concerns.append(f"the profile falls by {2 * fall:.3g} (in 2*delta) on its way out")
    hits = {}
    for row, ti in zip(eps[inside], t, strict=True) if not calibrated else ():
        for m, side in bounds_hit(row, bounds):
            if m != i:
                hits.setdefault((m, side), ti)
    for (m, side), ti in sorted(hits.items()):
        b = bounds[m][0 if side == "lower" else 1]
        concerns.append(
            f"eps[{m}] sits at its {side} bound {b:g} (from eps[{i}]={ti:.6g}): the "
            "chi-squared threshold does not hold there"
        )
    for side, outward in (("lower", values < lo), ("upper", values > hi)):
        if joint is None or calibrated or not outward.any():
            continue
        ks = np.flatnonzero(outward)
        for k in ks[::-1] if side == "lower" else ks:
            near = _at_bound(i, values[k], eps[k], bounds)
            if near:
                if delta[k] < joint:
                    m, where = near[0]
                    b = bounds[m][0 if where == "lower" else 1]
                    concerns.append(
                        f"eps[{m}] reaches its {where} bound {b:g} beyond the {side} end "
                        f"(at eps[{i}]={values[k]:.6g}, 2*delta = {2 * delta[k]:.3g}, inside "
                        f"the joint region's {2 * joint:.3g}): the chi-squared threshold "
                        "need not hold so near a bound"
                    )
                break
    if not calibrated:
        concerns += _nuisance_concerns(i, nuisance, inside, threshold)
    bad = [v[0] for f, v in unconverged if f == (i,) and lo <= v[0] <= hi]
    if bad:
        concerns.append(f"{len(bad)} inner fit(s) inside the interval did not converge")
    return tuple(concerns)
