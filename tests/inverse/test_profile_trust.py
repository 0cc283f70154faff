"""A profile's interval is flagged by the profile's own evidence (issue 37 item 4), not by
its distance to the delta-method interval: a skewed but regular profile is trusted, a
profile along which a re-optimized parameter sits at its bound is not (the chi-squared
threshold assumes an interior optimum), and so is one that stays below the threshold to
the parameter's bound."""

import numpy as np
import pytest
from _models import ridge_data, ridge_rod

from ecfm_uq.inverse import ModelProblem, SteadyProblem, fit, profile_likelihood
from ecfm_uq.inverse.statistics.profile import profile_concerns

S = np.array([0.02, 0.02, 0.06, 0.06, 0.11, 0.11, 0.22, 0.22, 0.56, 0.56, 1.10, 1.10])
RATE = np.array([76, 47, 97, 107, 123, 139, 159, 152, 191, 201, 207, 200], dtype=float)


def michaelis_menten(e):
    return e[0] * S / (e[1] + S)


def test_a_skewed_regular_profile_is_trusted():
    """Puromycin: K_m's likelihood interval is asymmetric against the delta method's
    (they disagree by 0.1 of the half-width and more), yet nothing is wrong with it."""
    res = fit(ModelProblem(michaelis_menten, RATE, names=["V_max", "K_m"]), [200.0, 0.1])
    prof = profile_likelihood(res)
    assert prof.disagree[1], prof.message
    assert prof.trusted.all(), prof.message
    assert "not trusted" not in prof.message


XS = np.array([0.2, 0.35, 0.5, 0.65, 0.8])
MODES = np.arange(1, 40, 2)


def rod(e):
    """-w'' + c w = s on (0, 1), w = 0 at both ends, read at five points: a reaction
    coefficient c inside the operator, singular as c -> -pi^2 (the readings blow up); the
    likelihood runs along a ridge (s / (pi^2 + c) nearly fixed) toward that end."""
    c, s = e
    shape = 4 / (MODES * np.pi) * np.sin(np.pi * np.outer(XS, MODES))
    return s * (shape / (MODES**2 * np.pi**2 + c)).sum(1)


def test_a_nuisance_parameter_at_its_bound_along_the_profile_is_flagged():
    truth = np.array([-8.0, 10.0])
    y0 = rod(truth)
    sigma = 0.05 * np.abs(y0).mean()
    y = y0 + sigma * np.random.default_rng(0).standard_normal(y0.size)
    res = fit(ModelProblem(rod, y, names=["c", "s"]), [-5.0, 8.0], bounds=[(-9.8, 50.0),
              (0.1, 100.0)], sigma=sigma)  # fmt: skip
    prof = profile_likelihood(res)
    # the profile of s re-optimizes c, which reaches its bound near the singularity
    concerns = prof.profiles[1].concerns
    assert any("eps[0] sits at its lower bound -9.8" in c for c in concerns), concerns
    assert not prof.trusted[1]
    assert "eps[1] interval not trusted" in prof.message


def test_concerns_read_the_profile_points():
    """Each rule on hand-made profile points: a regular profile has none."""
    values = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    delta = 0.5 * values**2
    eps = np.column_stack([values, np.zeros(5)])
    bounds = [(-10.0, 10.0), (-1.0, 1.0)]
    args = (0, values, delta, eps, (-2.0, 2.0), ("crossed", "crossed"))
    assert profile_concerns(*args, [(-2.0, 2.0)], 1.92, bounds) == ()
    # a fall on the way out (a second dip inside the interval)
    bumpy = delta.copy()
    bumpy[-1] = 0.1
    (c,) = profile_concerns(0, values, bumpy, *args[3:], [(-2.0, 2.0)], 1.92, bounds)
    assert "falls" in c
    # the other parameter at its bound inside the interval
    at = eps.copy()
    at[3:, 1] = 1.0
    (c,) = profile_concerns(0, values, delta, at, *args[4:], [(-2.0, 2.0)], 1.92, bounds)
    assert c.startswith("eps[1] sits at its upper bound 1 (from eps[0]=1)")
    # an open end, two regions, an inner fit that did not converge
    out = profile_concerns(0, values, delta, eps, (-2.0, 2.0), ("crossed", "the profile "
                           "stays below"), [(-2.0, 2.0), (5.0, 6.0)], 1.92, bounds,
                           [((0,), (1.0,)), ((1,), (0.5,))])  # fmt: skip
    assert out == ("upper end open", "2 regions below the threshold",
                   "1 inner fit(s) inside the interval did not converge")  # fmt: skip


@pytest.mark.parametrize("level", [0.9, 0.99])
def test_trusted_is_per_parameter_and_sized(level):
    res = fit(ModelProblem(michaelis_menten, RATE), [200.0, 0.1])
    prof = profile_likelihood(res, level, which=[1])
    assert prof.trusted.tolist() == [False, True]  # eps[0] not profiled: nothing to trust


def test_a_bound_inside_the_joint_region_beyond_an_end_is_evidence():
    """Outside the interval, the first point with a parameter at its bound counts when its
    delta is below the joint region's level (``joint``, 0.5 chi2_p in known-noise units):
    the bound is among the parameters the data do not exclude. Not when it is above, nor
    without ``joint``, nor with a calibrated threshold."""
    values = np.array([-3.0, -2.5, -2.0, -1.0, 0.0, 1.0, 2.0, 2.5, 3.0])
    delta = 0.5 * values**2
    eps = np.column_stack([values, np.zeros(values.size)])
    eps[-1, 1] = -1.0  # the re-optimized eps[1] at its lower bound beyond the upper end
    bounds = [(-3.0, 10.0), (-1.0, 1.0)]  # and eps[0] at its own lower bound at t = -3
    args = (0, values, delta, eps, (-1.96, 1.96), ("crossed", "crossed"), [(-1.96, 1.96)],
            1.92, bounds)  # fmt: skip
    assert profile_concerns(*args) == ()  # joint not given: the previous rule
    lower, upper = profile_concerns(*args, joint=5.0)  # 2*delta = 9 < 10 at both
    assert lower.startswith("eps[0] reaches its lower bound -3 beyond the lower end (at eps[0]=-3")
    assert upper.startswith("eps[1] reaches its lower bound -1 beyond the upper end (at eps[0]=3")
    assert profile_concerns(*args, joint=4.4) == ()  # 9 > 8.8: outside the region
    assert profile_concerns(*args, calibrated=True, joint=5.0) == ()
    # the first point at a bound outward decides: one above the level hides a lower one
    far = eps.copy()
    far[-2, 1] = -1.0  # 2*delta = 6.25 at t = 2.5, then 9 at t = 3
    (c,) = profile_concerns(0, values, delta, far, *args[4:], joint=3.2)
    assert "at eps[0]=2.5, 2*delta = 6.25" in c


def test_where_a_nuisance_first_reaches_its_bound_beyond_an_end_is_located():
    """bound_touches bisects between the last free point and the first at the bound: on
    the rod's ridge, the profile of s beyond its lower end meets c's bound where the
    profile is far lower than at the first computed point at the bound."""
    truth = np.array([-9.5, 10.0])
    y0 = rod(truth)
    sigma = 0.02 * np.abs(y0).mean()
    y = y0 + sigma * np.random.default_rng(6).standard_normal(y0.size)
    res = fit(ModelProblem(rod, y, names=["c", "s"]), truth, bounds=[(-9.7, 500.0),
              (0.01, 1000.0)], sigma=sigma)  # fmt: skip
    prof = profile_likelihood(res, which=[1]).profiles[1]
    lo = prof.interval[0]  # 34.5: the estimate is far up the ridge (c = -3.3, s = 177)
    below = prof.values < lo
    at = np.isclose(prof.eps[:, 0], -9.7, atol=1e-6)
    k = np.flatnonzero(below & at)[-1]  # the first point outward at c's bound
    free = np.flatnonzero(below & ~at)  # c off its bound: between it and the end
    assert free.size and prof.values[k] < prof.values[free].min()
    # the scan's first point at the bound is further out, where the profile is far higher
    first = np.flatnonzero(below & at)[-2]
    gap = prof.values[free].min() - prof.values[first]
    assert prof.values[first] < prof.values[k]
    assert prof.values[free].min() - prof.values[k] > gap / 2**9  # located, not the end
    assert prof.delta[k] < 0.01 * prof.delta[first]
    # and the bound is inside the joint 95 % region there (2*delta 5.85 < 5.99): flagged
    assert 2 * prof.delta[k] < 5.991
    (c,) = prof.concerns
    assert c.startswith("eps[0] reaches its lower bound -9.7 beyond the lower end")


def test_a_nuisance_variance_along_the_profile_is_evidence():
    """The random-force ECFM's tau-hat re-estimated at each profile point (``nuisance``:
    tau-hat and the variance term 1/2 log det S): positive inside the interval with the
    variance term moving by more than half the threshold, or 0 at some points and
    positive at others, is a concern; tau-hat = 0 throughout, a variance term that moves
    by less, or points outside the interval are not; a calibrated threshold has none."""
    values = np.array([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])
    delta = 0.5 * values**2
    eps = np.column_stack([values, np.zeros(values.size)])
    args = (0, values, delta, eps, (-2.0, 2.0), ("crossed", "crossed"), [(-2.0, 2.0)], 1.92,
            [(-10.0, 10.0), (-10.0, 10.0)])  # fmt: skip
    none = np.zeros((values.size, 2))
    assert profile_concerns(*args, nuisance=none) == ()
    moving = np.column_stack([np.full(values.size, 5.0), 0.6 * values])  # span 2.4 > 0.96
    (c,) = profile_concerns(*args, nuisance=moving)
    assert c.startswith("the variance term (1/2 log det of the data covariance, tau-hat up to 5)")
    assert "changes by 4.8 (in 2*delta) inside the interval of eps[0]" in c
    assert profile_concerns(*args, nuisance=moving, calibrated=True) == ()
    still = moving * [1.0, 0.2]  # the variance term moves by 0.48 < 0.96: no concern
    assert profile_concerns(*args, nuisance=still) == ()
    kink = still.copy()
    kink[:3, 0] = 0.0  # tau-hat 0 at t = -3, -2, -1: at its bound inside the interval
    (c,) = profile_concerns(*args, nuisance=kink)
    assert c.startswith("the nuisance tau-hat is 0 at part of the interval of eps[0]")
    outside = still.copy()
    outside[0, 0] = 0.0  # only at t = -3, outside [-2, 2]
    assert profile_concerns(*args, nuisance=outside) == ()


@pytest.mark.parametrize("n, fires", [(5, True), (0, False)])
def test_a_random_force_interval_shaped_by_tau_is_flagged(n, fires):
    """Data set 5 of the ridge: tau-hat = 165, the estimate far up the ridge (c = -30.9),
    c's interval [-48.0, -4.2] misses the truth -50 with the bound outside the joint
    region (2*delta = 7.3 there: no bound concern) -- the variance term moves by more
    than the threshold inside it, and the interval is flagged. Data set 0: tau-hat = 0
    along the whole profile (the standard likelihood): no such concern."""
    system, M = ridge_rod()
    truth = np.array([-50.0, 10.0])
    y, sigma = ridge_data(system, M, truth, n)
    res = fit(SteadyProblem(system, M, y), truth, formulation="ecfm-random", sigma=sigma,
              bounds=[(-50.0, 2000.0), (0.01, 1e5)])  # fmt: skip
    prof = profile_likelihood(res, which=[0])
    concerns = prof.profiles[0].concerns
    assert any(c.startswith("the variance term") for c in concerns) is fires, concerns
    if fires:
        assert res.extra["tau"] > 100
        lo, hi = prof.intervals[0]
        assert -49 < lo < -46 and -6 < hi < -2  # the miss
        assert not any("bound" in c for c in concerns), concerns
        assert "threshold='calibrated'" in prof.message
    else:
        assert res.extra["tau"] == 0.0


@pytest.mark.slow
def test_random_force_misses_on_a_ridge_to_a_bound_are_flagged_or_have_a_discrepancy():
    """Issue 37's ridge: -kappa w'' + c w = s read at five points, kappa pi^2 = 50.5, the
    user's bound c >= -50 just above the singular operator, truth (-50, 10) on it, 2 %
    noise. The random-force ECFM's intervals miss the truth far more often than 5 % (0.78
    and 0.83 of 120 data sets, docs/calibration.md): every miss of a fit with tau-hat = 0
    (the standard likelihood) is flagged by a bound inside the joint region; the misses
    left unflagged are those with a discrepancy estimated (tau-hat > 0), which pushes the
    estimate up the ridge, away from the bound; those are flagged by tau-hat's variance
    term changing inside the interval (every miss flagged)."""
    system, M = ridge_rod()
    truth = np.array([-50.0, 10.0])
    misses = []
    for n in range(20):
        y, sigma = ridge_data(system, M, truth, n)
        res = fit(SteadyProblem(system, M, y), truth, formulation="ecfm-random", sigma=sigma,
                  bounds=[(-50.0, 2000.0), (0.01, 1e5)])  # fmt: skip
        prof = profile_likelihood(res)
        for j in range(2):
            lo, hi = prof.intervals[j]
            if not lo <= truth[j] <= hi:
                misses.append((res.extra["tau"], bool(prof.profiles[j].concerns)))
    assert misses  # 4 of 40 intervals miss (data sets 4 and 5 of this stream)
    for tau, flagged in misses:
        assert flagged or tau > 0, misses
    assert any(flagged and tau == 0 for tau, flagged in misses), misses
    # and with tau-hat > 0 the variance term along the profile flags them too: every miss
    assert all(flagged for _, flagged in misses), misses
