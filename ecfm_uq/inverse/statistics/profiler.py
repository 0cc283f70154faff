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
from ..core.finite_differences import fd_gradient

__all__ = ["MODEL_FAILURES", "Profiler", "beyond", "walk"]

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
    # a residual too large to square is an infinitely bad point: inf is the answer the
    # callers test for (np.isfinite, S1 <= S), not a numerical accident to warn about
    with np.errstate(over="ignore"):
        return float(r @ r)


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
        g, A = J.T @ r, J.T @ J
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
            try:
                step = np.linalg.solve(A + mu * np.diag(d), -g)
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
