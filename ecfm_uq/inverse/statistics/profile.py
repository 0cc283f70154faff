"""Profile-likelihood intervals and likelihood-ratio tests of a fit.

The delta-method interval :math:`\\hat\\epsilon_i \\pm z\\,\\mathrm{se}_i` assumes the
log-likelihood is quadratic in :math:`\\epsilon` over the interval. With a parameter inside
the operator it often is not (a curved, banana-shaped likelihood) and the quick interval
covers the truth far less often than it says. The profile likelihood does not assume it
(Raue et al. 2009; lmfit's ``conf_interval``, pyPESTO, Data2Dynamics): for each parameter
:math:`\\epsilon_i`,

.. math::

    \\ell_p(t) = \\min_{\\epsilon:\\ \\epsilon_i = t} \\ell(\\epsilon), \\qquad
    \\{t : 2(\\ell_p(t) - \\ell(\\hat\\epsilon)) \\le \\chi^2_{1,\\,\\mathrm{level}}\\}

is the likelihood-ratio interval (Wilks). With :math:`\\sigma` estimated (profiled out) the
threshold is the profile-t one of Bates & Watts, :math:`\\tfrac n2\\log(1 +
F_{1,n-p}/(n-p))` (:func:`profile_threshold`: exact for a linear model, where the
chi-squared threshold under-covers with few data), and the delta-method intervals beside it
use the same rule (Student-t with :math:`n - p` degrees of freedom). Each profile point
re-optimizes the other parameters — by trust-region least squares on the residual for a
Gaussian likelihood (the Jacobian's free columns only), else L-BFGS-B on the exact gradient
(the adjoint where the problem uses it) — warm-started from the previous point; the profile
walks out from the estimate with steps sized by the delta-method standard error, growing
where the profile is flat, and the crossing is refined by Brent's method. A profile that
does not reach the threshold before the parameter's bound, before the model fails, or within
``max_steps`` steps gives that end as the bound or :math:`\\pm\\infty` with the reason: the
data do not bound the parameter on that side (practical non-identifiability) — never a
made-up finite end.

:func:`profile_likelihood` returns the profiles (for plotting) beside the intervals and
the delta-method intervals, flagging where the two disagree; :func:`profile_intervals` is
its (n_eps, 2) array; :func:`likelihood_ratio_test` tests a given :math:`\\epsilon`
(a point of a joint confidence region) with the others fixed or re-optimized.
"""

from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.interpolate import PchipInterpolator

from ..._validation import check_int, check_level, describe
from ...plotting import pyplot
from ...threads import library_threads
from ..core.convergence import bounds_arrays
from .profile_calibration import (
    Calibration,
    calibrate_ends,
    check_calibratable,
    noise_scale,
    order_statistic,
    simulator,
)
from .profile_walk import MODEL_FAILURES, Profiler, beyond, bound_touches, profile_concerns, walk
from .uncertainty import interval_quantile

__all__ = [
    "LikelihoodRatioTest",
    "Profile",
    "ProfileSummary",
    "likelihood_ratio_test",
    "profile_intervals",
    "profile_likelihood",
]

# two interval ends "agree" when they differ by less than this fraction of the
# delta-method half-width
AGREEMENT_RTOL = 0.1
_MAX_RECENTRE = 3  # profiles redone from a better point found along them


@dataclass(frozen=True)
class Profile:
    """The profile of one parameter.

    Attributes
    ----------
    index : int
    values : (k,) ndarray
        The fixed values :math:`t` of :math:`\\epsilon_i`, increasing (the estimate included).
    delta : (k,) ndarray
        :math:`\\ell_p(t) - \\ell(\\hat\\epsilon)`.
    eps : (k, n_eps) ndarray
        The re-optimized parameters along the profile.
    threshold : float
        The crossing level of ``delta`` (:func:`profile_threshold`).
    interval : (2,) ndarray
        The likelihood-ratio interval (an end may be a bound or infinite): the hull of
        ``regions``.
    reasons : tuple of str
        Why each end is where it is (``"crossed"`` or the reason it is open, or where the
        profile comes back below the threshold).
    delta_method : (2,) ndarray
        :math:`\\hat\\epsilon_i \\pm z\\,\\mathrm{se}_i` at the same level (NaN without
        standard errors).
    regions : tuple of (lower, upper)
        Every piece of the parameter's range where the profile is below the threshold:
        the one around the estimate, and beyond a rise toward a finite bound (a second
        basin, a ridge to the bound: :func:`profile_likelihood` scans to the bound).
    concerns : tuple of str
        The profile's own evidence against its interval (:func:`profile_concerns`): an
        open end, a second region, a branch that falls on its way out, a re-optimized
        parameter at its bound inside the interval (where the chi-squared threshold
        does not hold) or just beyond an end, inside the joint region (a ridge to a
        bound), an inner fit that did not converge. Empty when there is none.
    calibration : Calibration or None
        With ``threshold="calibrated"``: the simulated thresholds at the ends
        (:mod:`~.profile_calibration`); ``interval`` and ``regions`` then use them.
    """

    index: int
    values: np.ndarray
    delta: np.ndarray
    eps: np.ndarray
    threshold: float
    interval: np.ndarray
    reasons: tuple
    delta_method: np.ndarray
    regions: tuple = ()
    concerns: tuple = ()
    calibration: Calibration | None = None

    @property
    def threshold_used(self):
        """``"calibrated"`` (simulated at the ends: :attr:`calibration`) or ``"chi2"``."""
        return "chi2" if self.calibration is None else "calibrated"

    @property
    def trusted(self):
        """True when the profile shows no evidence against its interval (``concerns``
        empty); the distance to the delta-method interval is not such evidence."""
        return not self.concerns

    @property
    def agrees(self):
        """True when both ends are within ``AGREEMENT_RTOL`` of the delta-method half-width."""
        lo, hi = self.delta_method
        if not (np.isfinite(lo) and np.isfinite(hi)) or not np.all(np.isfinite(self.interval)):
            return False
        half = 0.5 * (hi - lo)
        return bool(np.all(np.abs(self.interval - self.delta_method) <= AGREEMENT_RTOL * half))

    def plot(self, ax=None, name=None):
        """Plot :math:`2\\Delta\\ell_p` with the threshold and both intervals.

        The computed profile points are markers; the curve through them is a monotone
        piecewise-cubic (PCHIP) interpolant, which neither overshoots nor invents a dip
        between them (the profile itself is not recomputed).

        Parameters
        ----------
        ax : matplotlib Axes, optional
        name : str, optional
            The parameter's name on the x axis (default ``eps[i]``).

        Returns
        -------
        matplotlib Axes
        """
        if ax is None:
            _, ax = pyplot().subplots(figsize=(4.5, 3.2))
        name = name or f"eps[{self.index}]"
        t, y = _smooth_profile(self.values, 2 * np.asarray(self.delta, dtype=float))
        ax.plot(t, y, "-", color="C0", label="profile likelihood")
        ax.plot(self.values, 2 * self.delta, "o", ms=3, color="C0", label="computed points")
        ax.axhline(2 * self.threshold, color="k", lw=0.8, ls=":")
        if self.calibration is not None:
            t_c = [q[0] for q in self.calibration.points]
            ax.plot(t_c, [2 * q[1] for q in self.calibration.points], "x", color="k", ms=5,
                    label="calibrated threshold")  # fmt: skip
        for x in self.interval:
            if np.isfinite(x):
                ax.axvline(x, color="C0", lw=0.8)
        for x in self.delta_method:
            if np.isfinite(x):
                ax.axvline(x, color="C1", lw=0.8, ls="--")
        ax.plot([], [], color="C1", ls="--", label="delta method")
        ax.set_xlabel(name)
        ax.set_ylabel(r"$2\,\Delta\ell$")
        ax.legend(fontsize=7)
        return ax


def _smooth_profile(values, y, per_gap=24):
    """A PCHIP curve through the finite profile points, ``per_gap`` points per interval
    (the points themselves when fewer than three are finite)."""
    t = np.asarray(values, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    t, first = np.unique(t, return_index=True)  # increasing, one value per t
    y = y[first]
    if t.size < 3:
        return t, y
    tt = np.concatenate(
        [np.linspace(a, b, per_gap, endpoint=False) for a, b in zip(t[:-1], t[1:], strict=True)]
        + [t[-1:]]
    )
    return tt, PchipInterpolator(t, y)(tt)


@dataclass(frozen=True)
class ProfileSummary:
    """Every profile of a fit, its intervals and the delta-method intervals beside them.

    Attributes
    ----------
    level : float
    intervals : (n_eps, 2) ndarray
        Likelihood-ratio intervals (NaN rows for parameters not profiled).
    delta_intervals : (n_eps, 2) ndarray
    profiles : dict of int -> Profile
    disagree : (n_eps,) bool ndarray
        True where the delta-method interval is not to be trusted (an end off by more than
        ``AGREEMENT_RTOL`` of its half-width, or an open profile end).
    message : str
    regions : dict of int -> list of (lower, upper)
        Each profiled parameter's pieces below the threshold (``intervals`` are their
        hulls).
    trusted : (n_eps,) bool ndarray
        True where the profile shows no evidence against its interval
        (:attr:`Profile.concerns`, listed in ``message``); False for a parameter not
        profiled. ``disagree`` is about the delta method, this is about the profile.
    estimate : (n_eps,) ndarray or None
        The estimate of the fit profiled (``result.eps``): a table of another fit refuses
        these intervals.
    """

    level: float
    intervals: np.ndarray
    delta_intervals: np.ndarray
    profiles: dict = field(default_factory=dict)
    disagree: np.ndarray = None
    message: str = ""
    regions: dict = field(default_factory=dict)
    trusted: np.ndarray = None
    names: tuple = ()
    estimate: np.ndarray = None

    @property
    def threshold_used(self):
        """Per parameter, the threshold its interval used (``"chi2"``, ``"calibrated"``;
        None where not profiled)."""
        n = len(self.intervals)
        return tuple(self.profiles[i].threshold_used if i in self.profiles else None
                     for i in range(n))  # fmt: skip

    def plot(self, ax=None, names=None):
        """One panel per profiled parameter (:meth:`Profile.plot`).

        Parameters
        ----------
        ax : sequence of matplotlib Axes, optional
            One per profiled parameter (default: a new 1 x k figure).
        names : sequence of str, optional
            Names of all parameters (default: the fit's ``names``, else ``eps[i]``).

        Returns
        -------
        (k,) ndarray of matplotlib Axes
            ``axes[0].figure`` is the figure.
        """
        idx = sorted(self.profiles)
        names = list(self.names) if names is None else [str(n) for n in names]
        if names and len(names) <= max(idx, default=-1):
            raise ValueError(
                f"`names` must name all {max(idx) + 1} parameters (the profiles are of "
                f"{idx}), got {len(names)}"
            )
        if ax is None:
            fig, ax = pyplot().subplots(1, len(idx), figsize=(4.2 * len(idx), 3.2), squeeze=False)
        axes = np.asarray(ax, dtype=object).reshape(-1)
        if axes.size != len(idx):
            raise ValueError(f"`ax` must hold {len(idx)} Axes (one per profile), got {axes.size}")
        for a, i in zip(axes, idx, strict=True):
            self.profiles[i].plot(a, names[i] if names else None)
        axes[0].figure.tight_layout()
        return axes


@dataclass(frozen=True)
class LikelihoodRatioTest:
    """:math:`2(\\ell(\\epsilon_0) - \\ell(\\hat\\epsilon))` against :math:`\\chi^2_{\\mathrm{dof}}`."""

    statistic: float
    dof: int
    p_value: float
    eps: np.ndarray


def profile_threshold(like, level, k=1):
    """The crossing level of :math:`\\ell_p(t) - \\hat\\ell` (of a joint region of ``k``
    parameters: :math:`\\chi^2_k`, :math:`kF_{k,n-p}`).

    Known noise: :math:`\\tfrac12\\chi^2_{1,\\mathrm{level}}` (Wilks). Sigma profiled out
    (:math:`\\ell = \\tfrac n2\\log S`, :math:`S` the sum of squares): the profile-t
    interval of Bates & Watts (1988, Sec. 6.1), :math:`S(t) \\le S(\\hat\\epsilon)\\,(1 +
    F_{1,n-p,\\mathrm{level}}/(n - p))`, i.e. :math:`\\tfrac n2\\log(1 + F/(n - p))`, which
    is exact for a model linear in its parameters (the t interval) and does not
    under-cover with few data as the chi-squared threshold does.
    """
    if like.noise == "profiled sigma":
        dof = like.n_data - like.n_eps
        F = stats.f.ppf(level, k, dof)
        return 0.5 * like.n_data * np.log1p(k * F / dof)
    return 0.5 * stats.chi2.ppf(level, k)


def _quantile(result, level):
    """The delta-method quantile at ``level`` on the fit's own rule: Student-t with the
    uncertainty's ``dof`` where sigma was estimated, normal otherwise."""
    unc = result.uncertainty
    return interval_quantile(level, None if unc is None else unc.dof)


def _likelihood(result):
    # the random-force ECFM's intervals profile tau out (result.interval_likelihood); a
    # string there says why they cannot: they hold tau at its estimate (result.likelihood)
    like = getattr(result, "interval_likelihood", None)
    if like is None or isinstance(like, str):
        like = getattr(result, "likelihood", None)
    if like is None or isinstance(like, str):
        why = like or "it was not made by ecfm_uq.inverse.fit"
        raise ValueError(f"`result` has no likelihood to profile: {why}")
    return like


def _check_level(level):
    return check_level("level", level)


def _which(which, n, names):
    """The indices of ``which`` (indices or parameter names), checked."""
    if which is None:
        return list(range(n))
    items = [which] if isinstance(which, str | numbers.Integral) else list(np.ravel(which))
    known = list(names) if names else []
    out = []
    for w in items:
        if isinstance(w, str | np.str_):
            if str(w) not in known:
                raise ValueError(
                    f"`which` names {str(w)!r}, not a parameter name; the names are "
                    f"{known or 'not set (pass names= to the problem)'}; or pass indices"
                )
            out.append(known.index(str(w)))
        elif isinstance(w, numbers.Integral) and not isinstance(w, bool):
            if not 0 <= int(w) < n:
                raise ValueError(f"`which` holds {int(w)}, not a parameter index in [0, {n})")
            out.append(int(w))
        else:
            raise TypeError(f"`which` must hold parameter indices or names, got {describe(w)}")
    return out


def _bounds(result, bounds, n):
    if bounds is None:
        bounds = getattr(result, "bounds", None)
    if bounds is None:
        return [(-np.inf, np.inf)] * n
    if len(bounds) != n:
        raise ValueError(f"`bounds` must have one (lo, hi) pair per parameter ({n})")
    lo, hi = bounds_arrays(bounds, n)
    return list(zip(lo.tolist(), hi.tolist(), strict=True))


def _observed_information(like, eps_hat, step):
    """:math:`\\nabla^2\\ell(\\hat\\epsilon)` by central differences of the exact gradient
    (symmetrized), or None where the model cannot be solved around the estimate."""
    n = eps_hat.size
    H = np.empty((n, n))
    try:
        for j in range(n):
            e = np.zeros(n)
            e[j] = step[j]
            H[:, j] = (like(eps_hat + e)[1] - like(eps_hat - e)[1]) / (2 * step[j])
    except MODEL_FAILURES:
        return None
    return 0.5 * (H + H.T)


def _scales(result, like, eps_hat):
    """The fit's delta-method standard errors (NaN where it has none), the observed
    information's inverse (None if not positive definite) and each parameter's step scale."""
    unc = result.uncertainty
    se = None if unc is None else unc.stderr
    se = np.full(eps_hat.size, np.nan) if se is None else np.asarray(se, dtype=float)
    have = np.isfinite(se) & (se > 0)
    step = 1e-4 * np.where(have, se, np.maximum(1.0, np.abs(eps_hat)))
    H = _observed_information(like, eps_hat, step)
    naive = None
    if H is not None and np.all(np.isfinite(H)):
        w = np.linalg.eigvalsh(H)
        if w[0] > 1e-12 * max(w[-1], 0.0):
            naive = np.linalg.inv(H)
    fallback = 0.1 * np.maximum(1.0, np.abs(eps_hat))
    if naive is not None:
        fallback = np.where(have, se, np.sqrt(np.diag(naive)))
    # a flat direction (practically non-identifiable) has a huge standard error: cap the
    # step scale at the parameter's magnitude so steps stay where the model can be solved
    scale = np.minimum(np.where(have, se, fallback), np.maximum(1.0, np.abs(eps_hat)))
    return se, naive, scale


def _profiles(prof, which, threshold, z, bnds, max_steps, delta_ci, n_scan, simulate=None,
              joint=None):  # fmt: skip
    """Every requested profile, and (decrease, eps) of the lowest point found below the
    estimate's likelihood (None when the estimate is the minimum)."""
    profiles, best = {}, None
    for i in which:
        # a quadratic profile crosses z standard errors out: ~3 steps
        step = z * prof.scale[i] / 3
        ends, reasons, pts = [], [], [(prof.eps_hat[i], 0.0, prof.eps_hat)]
        far = []
        for direction, bound in ((-1, bnds[i][0]), (1, bnds[i][1])):
            p, end, why = walk(prof, i, direction, threshold[i], step, bound, max_steps)
            pts += p
            if why == "crossed" and np.isfinite(bound) and n_scan > 0:
                q, regions = beyond(prof, i, direction, threshold[i], end, p[-1][2], bound, n_scan)
                pts += q
                far += regions
                if regions:
                    why = (
                        f"crossed at {end:.6g}, but the profile falls below the threshold "
                        f"again beyond it: {[tuple(np.round(r, 6)) for r in regions]}"
                    )
            if np.isfinite(end) and why.startswith("crossed"):
                # the crossing itself: where the re-optimized parameters sit at the end
                pts.append((end, *prof.at(i, end, p[-1][2])))
            ends.append(end)
            reasons.append(why)
        chi2_ends, calibration = tuple(ends), None
        if simulate is not None:
            ends, reasons, calibration = calibrate_ends(
                prof, i, ends, reasons, pts, step, bnds[i], max_steps, simulate(i)
            )
            # the chi-squared scan's far regions: one that meets the calibrated one joins it
            for r in [r for r in far if r[0] <= ends[1] and r[1] >= ends[0]]:
                far.remove(r)
                ends = [min(ends[0], r[0]), max(ends[1], r[1])]
        if simulate is None:  # where a parameter first reaches its bound beyond the ends
            pts += bound_touches(prof, i, pts, ends, bnds)
        regions = sorted([(ends[0], ends[1]), *far])
        hull = (min(r[0] for r in regions), max(r[1] for r in regions))
        pts.sort(key=lambda q: q[0])
        k = int(np.argmin([q[1] for q in pts]))
        if pts[k][1] < -1e-6 * max(1.0, threshold[i]) and (best is None or pts[k][1] < best[0]):
            best = (pts[k][1], pts[k][2])
        values = np.array([q[0] for q in pts])
        delta = np.array([q[1] for q in pts])
        eps = np.array([q[2] for q in pts])
        concerns = profile_concerns(
            i, values, delta, eps, (ends[0], ends[1]), reasons, regions, threshold[i], bnds,
            prof.unconverged, calibration is not None, None if joint is None else joint[i],
            prof.nuisance_along(eps) if calibration is None else None,
        )  # fmt: skip
        if calibration is not None:
            calibration = Calibration(*calibration, np.array(chi2_ends, dtype=float))
        profiles[i] = Profile(
            i, values, delta, eps, threshold[i], np.array(hull, dtype=float), tuple(reasons),
            delta_ci[i], tuple(regions), concerns, calibration,
        )  # fmt: skip
    return profiles, best


@library_threads()
def profile_likelihood(result, level=0.95, *, which=None, bounds=None, max_steps=40, scan=12,
                       threshold="chi2", n_simulations=200, seed=0):  # fmt: skip
    """Profiles, likelihood-ratio intervals and delta-method intervals of a fit.

    Parameters
    ----------
    result : InverseResult
        From :func:`~ecfm_uq.inverse.fit` of a formulation with a likelihood (see
        :mod:`ecfm_uq.inverse.statistics.loglik`): ``result.likelihood``.
    level : float
        Confidence level in (0, 1).
    which : int, str or sequence of them, optional
        Parameters to profile, by index or by name (``result.names``; default: all).
    bounds : sequence of (lo, hi), optional
        Where the profiles stop (default: the fit's ``bounds``; open otherwise).
    max_steps : int
        Steps per side before an end is declared open.
    scan : int
        Points on which the range between a crossing and a finite bound is searched for
        a return below the threshold (``regions``); 0 stops at the crossing. A side
        without a bound is followed to its crossing only: give bounds to have the whole
        admissible range searched.
    threshold : {"chi2", "calibrated"}
        ``"chi2"``: Wilks' :math:`\\tfrac12\\chi^2_{1}` (the profile-t one with sigma
        profiled out, :func:`profile_threshold`). ``"calibrated"``: the likelihood-ratio
        threshold simulated at each end (parametric bootstrap from the profiled point,
        :mod:`~.profile_calibration`) where the chi-squared one does not hold: a
        re-optimized parameter at its bound along the profile (a ridge to a bound), a
        near-singular model. Gaussian least-squares likelihoods and the random-force
        ECFM's (its forces simulated with the profiled tau where the data reject tau = 0,
        else none); 2-3 simulated thresholds per end, each ``2 * n_simulations`` small
        fits.
    n_simulations : int
        Simulated data sets per calibrated threshold (at least 20).
    seed : int
        Seed of the simulations (the same noise at every point of a profile).

    Returns
    -------
    ProfileSummary

    Raises
    ------
    ValueError
        If ``result`` has no likelihood (ECFM's force objective, the penalty form, ...)
        or ``level`` is not in (0, 1).
    """
    like = _likelihood(result)
    level = _check_level(level)
    n = like.n_eps
    which = _which(which, n, getattr(result, "names", None))
    max_steps = check_int("max_steps", max_steps, minimum=1)
    scan = check_int("scan", scan, minimum=0)
    if threshold not in ("chi2", "calibrated"):
        raise ValueError(f'`threshold` must be "chi2" or "calibrated", got {threshold!r}')
    n_simulations = check_int("n_simulations", n_simulations, minimum=20)
    if order_statistic(n_simulations, level) > n_simulations:
        raise ValueError(
            f"`n_simulations` = {n_simulations} cannot give a {level:g} quantile (the "
            f"{order_statistic(n_simulations, level)}-th of them): pass at least "
            f"{int(np.ceil(level / (1 - level)))}"
        )
    seed = check_int("seed", seed, minimum=0)
    if threshold == "calibrated":
        check_calibratable(like)
    bnds = _bounds(result, bounds, n)
    eps_hat = np.asarray(result.eps, dtype=float)
    for i, (lo, hi) in enumerate(bnds):
        if not lo <= eps_hat[i] <= hi:
            raise ValueError(
                f"`bounds[{i}]` = {(lo, hi)} excludes the estimate eps[{i}] = {eps_hat[i]:.6g}: "
                "a profile starts at the estimate; widen the bounds to contain it"
            )
    ell_hat, _ = like(eps_hat)
    if not np.isfinite(ell_hat):
        raise ValueError(
            f"the likelihood is not finite at the estimate ({ell_hat}); an exact fit with "
            "sigma unknown has no likelihood interval: pass `sigma` to fit"
        )
    se, naive, scale = _scales(result, like, eps_hat)
    kind, threshold = threshold, np.full(n, profile_threshold(like, level))
    if like.noise == "replicated" and naive is not None:
        # a pseudo-likelihood is not the data's likelihood: its curvature is not the
        # estimate's precision. Magnitude adjustment (Chandler & Bate 2007): scale the
        # threshold by the robust (sandwich) over the naive (inverse-Hessian) variance
        robust = np.where(np.isfinite(se), se**2, np.diag(naive))
        threshold = threshold * robust / np.diag(naive)
    # the joint region's level: a bound inside it is evidence against an interval
    joint = threshold * (profile_threshold(like, level, n) / profile_threshold(like, level))
    z = _quantile(result, level)
    delta_ci = np.column_stack([eps_hat - z * se, eps_hat + z * se])

    recentred = []
    for _ in range(_MAX_RECENTRE + 1):
        simulate = None
        if kind == "calibrated":
            sd = noise_scale(like, ell_hat)

            def simulate(i, sd=sd):
                return simulator(like, i, level, scale, bnds, sd, n_simulations, seed)

        profiles, best = _profiles(
            Profiler(like, eps_hat, ell_hat, scale, bnds), which, threshold, z, bnds,
            max_steps, delta_ci, scan, simulate, joint,
        )  # fmt: skip
        if best is None:
            break
        # a profile found a lower likelihood: the fit did not end at its optimum; the
        # intervals are relative to the best point found, so profile again from there
        recentred.append(f"{best[0]:.3g} lower at eps={np.round(best[1], 6).tolist()}")
        ell_hat, eps_hat = ell_hat + best[0], best[1]
    notes = []
    if recentred:
        notes.append(
            "the fit did not end at its optimum: the profiles found a likelihood "
            + ", then ".join(recentred)
            + "; the intervals are around the best point found"
        )
    intervals = np.full((n, 2), np.nan)
    for i, prof_i in profiles.items():
        intervals[i] = prof_i.interval
        notes += [
            f"eps[{i}] {side} {'side' if r.startswith('crossed') else 'end open'}: {r}"
            for side, r in zip(("lower", "upper"), prof_i.reasons, strict=True)
            if r != "crossed"
        ]
    disagree = np.array([i in profiles and not profiles[i].agrees for i in range(n)])
    for i in np.flatnonzero(disagree & ~np.isfinite(se)):
        notes.append(f"eps[{i}]: the fit has no delta-method standard error to compare with")
    for i in np.flatnonzero(disagree & np.isfinite(se)):
        notes.append(
            f"eps[{i}]: the likelihood interval {intervals[i].round(6).tolist()} and the "
            f"delta-method interval {delta_ci[i].round(6).tolist()} disagree (a likelihood "
            "that is not quadratic there: prefer the likelihood interval)"
        )
    trusted = np.array([i in profiles and profiles[i].trusted for i in range(n)])
    for i, prof_i in profiles.items():
        cal = prof_i.calibration
        if cal is not None:
            notes.append(
                f"eps[{i}]: calibrated thresholds (2*delta) "
                f"{np.round(2 * cal.thresholds, 3).tolist()} at the ends ({cal.n_simulations} simulations each; chi-squared "
                f"{2 * prof_i.threshold:.3g}, interval {cal.chi2_interval.round(6).tolist()})"
            )
        if prof_i.concerns:
            notes.append(
                f"eps[{i}] interval not trusted: " + "; ".join(prof_i.concerns)
                + ("" if cal is not None or not any("bound" in c or "tau" in c
                                                    for c in prof_i.concerns)
                   else "; threshold='calibrated' simulates the threshold at the ends")
            )  # fmt: skip
    regions = {i: list(prof_i.regions) for i, prof_i in profiles.items()}
    names = tuple(getattr(result, "names", None) or ())
    summary = ProfileSummary(
        level, intervals, delta_ci, profiles, disagree, "; ".join(notes), regions, trusted,
        names if len(names) == n else (), np.array(result.eps, dtype=float),
    )  # fmt: skip
    return summary


def profile_intervals(result, level=0.95, **kw):
    """Likelihood-ratio (profile-likelihood) intervals of a fit, an (n_eps, 2) array.

    See :func:`profile_likelihood` for the parameters and the method. An end the data do
    not bound is the parameter's bound or infinite (the reason is in the
    :func:`profile_likelihood` summary's ``message``). A ``UserWarning`` says when an interval
    disagrees with the delta-method one.
    """
    summary = profile_likelihood(result, level, **kw)
    if summary.disagree.any():
        warnings.warn(summary.message, UserWarning, stacklevel=2)
    return summary.intervals


@library_threads()
def likelihood_ratio_test(result, eps, *, free=None):
    """Test :math:`H_0: \\epsilon = \\epsilon_0` (or a subset of it) by the likelihood ratio.

    Parameters
    ----------
    result : InverseResult
        A fit with a likelihood.
    eps : (n_eps,) array_like
        The hypothesized parameters; ``eps[free]`` are only starting values.
    free : sequence of int, optional
        Parameters re-optimized under :math:`H_0` (nuisance parameters); the test then has
        ``n_eps - len(free)`` degrees of freedom.

    Returns
    -------
    LikelihoodRatioTest
        ``p_value`` of :math:`2(\\ell_0 - \\hat\\ell)` against :math:`\\chi^2_{\\mathrm{dof}}`;
        ``eps`` is the point tested (with its free parameters re-optimized). ``eps`` lies
        in the joint ``level`` confidence region iff ``p_value >= 1 - level``.
    """
    like = _likelihood(result)
    n = like.n_eps
    eps = np.asarray(eps, dtype=float)
    if eps.shape != (n,) or not np.all(np.isfinite(eps)):
        raise ValueError(f"`eps` must be {n} finite parameter values, got {eps.tolist()}")
    free = [] if free is None else sorted({int(j) for j in np.atleast_1d(free)})
    if any(not 0 <= j < n for j in free) or len(free) >= n:
        raise ValueError(f"`free` must name fewer than {n} parameter indices in [0, {n})")
    fixed = np.setdiff1d(np.arange(n), free)
    eps_hat = np.asarray(result.eps, dtype=float)
    ell_hat, _ = like(eps_hat)
    se, naive, scale = _scales(result, like, eps_hat)
    prof = Profiler(like, eps_hat, ell_hat, scale, _bounds(result, None, n))
    start = eps_hat.copy()
    start[fixed] = eps[fixed]
    d, at = prof.at(fixed, eps[fixed], start)
    stat = max(2.0 * d, 0.0)
    if like.noise == "replicated":
        if fixed.size > 1 or naive is None or not np.isfinite(se[fixed[0]]):
            raise ValueError(
                "a pseudo-likelihood ratio is calibrated (Chandler & Bate's adjustment) for "
                "one tested parameter with a sandwich standard error only; pass `free` with "
                "all other parameters"
            )
        stat *= naive[fixed[0], fixed[0]] / se[fixed[0]] ** 2
    dof = len(fixed)
    return LikelihoodRatioTest(stat, dof, float(stats.chi2.sf(stat, dof)), at)
