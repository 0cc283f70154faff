"""Profile-likelihood intervals of the random-force ECFM carry tau's uncertainty (issue 20).

The intervals profile :math:`g(\\epsilon) = \\ell(\\epsilon, \\hat\\tau(\\epsilon))`: the
marginal likelihood with the discrepancy variance re-estimated by REML at every
:math:`\\epsilon` (the function the estimate minimizes). The truth here is a brute-force
computation that shares nothing with the library's but the model solve: readings and their
derivatives by finite differences of ``solve_steady``, the error contrasts from
``scipy.linalg.null_space``, the restricted likelihood and the marginal likelihood from
dense determinants, each minimization by its own scalar search.
"""

import warnings

import numpy as np
import pytest
from scipy import linalg, optimize, stats

from ecfm_uq.inverse import SteadyProblem, fit, profile_likelihood
from ecfm_uq.inverse.core.fitter import holds
from ecfm_uq.problems.reaction import ReactionRod
from ecfm_uq.system import solve_steady


def _missing_source_fit(**options):
    rod = ReactionRod(6)
    clean = rod.data([1.5, 20.0], source=8.0)
    sigma = 0.02 * float(np.abs(clean).mean())
    v = clean + sigma * np.random.default_rng(1).standard_normal(clean.size)
    problem = SteadyProblem(rod.system, rod.M_obs, v)
    res = fit(problem, [1.5, 20.0], formulation="ecfm-random", sigma=sigma, options=options)
    return rod, v, sigma, res


class _BruteForce:
    """:math:`g(\\epsilon)` from dense linear algebra and finite differences."""

    def __init__(self, rod, v, sigma):
        self.rod, self.v, self.s2 = rod, v, sigma**2
        self.n_forces = rod.system.Gamma.shape[1]

    def readings(self, eps, lam=None):
        sol = solve_steady(self.rod.system, eps, lam=lam, strict=True)
        return self.rod.M_obs @ sol.Theta[:, 0]

    def __call__(self, eps):
        eps = np.asarray(eps, float)
        m0 = self.readings(eps)
        r = self.v - m0
        # force-to-sensor map: the model is linear in the forces, one solve per force
        A = np.column_stack(
            [self.readings(eps, lam) - m0 for lam in np.eye(self.n_forces)]
        )  # fmt: skip
        h = 1e-6 * np.maximum(1.0, np.abs(eps))
        J = np.column_stack(
            [(self.readings(eps + h[j] * e) - self.readings(eps - h[j] * e)) / (2 * h[j])
             for j, e in enumerate(np.eye(eps.size))]
        )  # fmt: skip
        K = linalg.null_space(J.T)
        AA, C = A @ A.T, r.size

        def reml(t):  # -log restricted likelihood of the contrasts K^T r at tau^2 = t
            S = K.T @ (self.s2 * np.eye(C) + t * AA) @ K
            return 0.5 * (np.linalg.slogdet(S)[1] + (K.T @ r) @ np.linalg.solve(S, K.T @ r))

        scale = self.s2 / np.trace(AA) * C
        grid = np.concatenate([[0.0], scale * np.logspace(-6, 10, 161)])
        vals = [reml(t) for t in grid]
        k = int(np.argmin(vals))
        t_hat = grid[k]
        if k > 0:
            lo, hi = np.log(grid[k - 1] if k > 1 else grid[1] / 10), np.log(grid[min(k + 1, 161)])
            res = optimize.minimize_scalar(
                lambda u: reml(np.exp(u)), bounds=(lo, hi), method="bounded",
                options={"xatol": 1e-12},
            )  # fmt: skip
            t_hat = float(np.exp(res.x)) if res.fun < vals[k] else t_hat
        S = self.s2 * np.eye(C) + t_hat * AA
        return 0.5 * (r @ np.linalg.solve(S, r) + np.linalg.slogdet(S)[1]), t_hat

    def profile(self, i, value, around):
        """min over the other parameter of g, with eps[i] = value (bounded scalar search
        on a window around ``around``, the other parameter's value there)."""
        j = 1 - i

        def f(x):
            e = np.empty(2)
            e[i], e[j] = value, x
            return self(e)[0]

        w = 3.0 * max(1.0, abs(around))
        xs = np.linspace(around - w, around + w, 41)
        k = int(np.argmin([f(x) for x in xs]))
        res = optimize.minimize_scalar(
            f, bounds=(xs[max(k - 1, 0)], xs[min(k + 1, 40)]), method="bounded",
            options={"xatol": 1e-9},
        )  # fmt: skip
        return res.fun


@pytest.mark.slow
def test_profile_re_estimates_tau_and_matches_a_brute_force_computation():
    rod, v, sigma, res = _missing_source_fit()
    assert res.success and res.extra["tau"] > 0, "the source must give tau-hat > 0"
    assert res.interval_likelihood is not None
    bf = _BruteForce(rod, v, sigma)
    g_hat, tau2_hat = bf(res.eps)
    # the estimate's tau is the brute-force REML one at the estimate
    np.testing.assert_allclose(res.extra["tau"] ** 2, tau2_hat, rtol=1e-5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # delta-method disagreement notes
        summary = profile_likelihood(res)
    assert "did not end at its optimum" not in summary.message
    half = 0.5 * stats.chi2.ppf(0.95, 1)
    for i in (0, 1):
        prof = summary.profiles[i]
        # delta along the profile: points well inside and beyond the threshold
        for t, d, e in zip(prof.values, prof.delta, prof.eps, strict=True):
            if 0.2 * half < d < 3 * half:
                d_bf = bf.profile(i, t, e[1 - i]) - g_hat
                assert abs(d - d_bf) < 1e-5 * max(1.0, d_bf), (i, t, d, d_bf)
        # both ends are the brute-force crossings of the chi2_1 threshold
        for end, other in zip(prof.interval, (prof.eps[0], prof.eps[-1]), strict=True):
            assert np.isfinite(end)
            width = abs(end - res.eps[i])
            lo, hi = sorted((end - 0.05 * width, end + 0.05 * width))
            crossing = optimize.brentq(
                lambda t, i=i, o=other: bf.profile(i, t, o[1 - i]) - g_hat - half, lo, hi,
                xtol=1e-10,
            )  # fmt: skip
            assert abs(end - crossing) < 1e-4 * width, (i, end, crossing)


def test_held_tau_stays_available_and_differs_where_tau_varies():
    _, _, _, prof = _missing_source_fit()
    _, _, _, held = _missing_source_fit(tau_in_intervals="held")
    assert held.interval_likelihood is None
    np.testing.assert_allclose(held.eps, prof.eps, rtol=0, atol=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        a = profile_likelihood(prof).intervals
        b = profile_likelihood(held).intervals
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    # tau-hat(eps) changes along the profiles: the two intervals are not the same
    assert np.max(np.abs(a - b) / (b[:, 1:] - b[:, :1])) > 1e-3
    with pytest.raises(ValueError, match="tau_in_intervals"):
        _missing_source_fit(tau_in_intervals="fixed")


def test_where_tau_hat_is_zero_along_the_profile_it_is_the_standard_profile():
    """Consistent data whose REML tau-hat is zero at the estimate and at every profile point:
    the profiled marginal likelihood is the standard likelihood there, so the intervals are
    the standard fit's."""
    from ecfm_uq.inverse.formulations.random_forces import RandomForceModel

    rod = ReactionRod(6)
    clean = rod.data([1.5, 20.0])
    sigma = 0.02 * float(np.abs(clean).mean())
    v = clean + sigma * np.random.default_rng(0).standard_normal(clean.size)
    problem = SteadyProblem(rod.system, rod.M_obs, v)
    res = fit(problem, [1.5, 20.0], formulation="ecfm-random", sigma=sigma)
    std = fit(problem, [1.5, 20.0], formulation="standard", sigma=sigma)
    assert res.extra["tau"] == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        ours, theirs = profile_likelihood(res), profile_likelihood(std)
    model = RandomForceModel(problem, sigma)
    for prof in ours.profiles.values():
        for e in prof.eps:
            assert model.best_s(model.linearize(e))[0] == 0.0  # the premise: tau-hat(eps) = 0
    np.testing.assert_allclose(ours.intervals, theirs.intervals, rtol=1e-6)


def test_delta_method_falls_back_to_gauss_newton_with_tau_held_and_says_why():
    """Where the observed information of the profiled likelihood is not positive definite,
    the uncertainty is (J^T S^-1 J)^-1 with S at tau-hat, computed here independently."""
    from ecfm_uq.inverse.formulations.random_forces import RandomForceModel, _uncertainty

    rod, v, sigma, res = _missing_source_fit()
    model = RandomForceModel(SteadyProblem(rod.system, rod.M_obs, v), sigma)
    lin = model.linearize(res.eps)
    g_hat = model.variances(lin)[0]
    standard = res.extra["standard"]
    scale = np.ones(2)
    x = np.asarray(res.eps) - np.asarray(standard.eps)

    def saddle(y):  # a profiled likelihood with negative curvature in one direction
        return float((y[0] - x[0]) ** 2 - (y[1] - x[1]) ** 2)

    u = _uncertainty(saddle, x, scale, standard, g_hat, model, lin)
    assert u.success and u.method == "gauss-newton-held-tau"
    assert "not positive definite" in u.message and "tau" in u.message
    bf = _BruteForce(rod, v, sigma)
    m0 = bf.readings(res.eps)
    A = np.column_stack([bf.readings(res.eps, lam) - m0 for lam in np.eye(bf.n_forces)])
    h = 1e-6 * np.maximum(1.0, np.abs(res.eps))
    J = np.column_stack(
        [(bf.readings(res.eps + h[j] * e) - bf.readings(res.eps - h[j] * e)) / (2 * h[j])
         for j, e in enumerate(np.eye(2))]
    )  # fmt: skip
    S = sigma**2 * np.eye(v.size) + res.extra["tau"] ** 2 * A @ A.T
    cov = np.linalg.inv(J.T @ np.linalg.solve(S, J))
    np.testing.assert_allclose(u.cov, cov, rtol=1e-5)
    # the fit itself: tau > 0, the search ended by Fisher scoring, and a positive
    # definite expected information there (the observed one's tag before)
    assert res.uncertainty.success and res.uncertainty.method == "marginal-likelihood-expected"


def test_an_open_profile_does_not_recentre_where_the_reaction_rate_underflows():
    """4 sensors: the data do not bound the reaction rate below, the eps0 profile walks out
    to 10^eps0 = 0, where the parameter has no effect and the REML contrasts would gain a
    dimension (tau-hat and the likelihood jumping with them). Before that was refused, the
    profile of this data set 're-centred' on eps0 ~ -7e11 at a likelihood 0.2 lower."""
    rod = ReactionRod(4)
    clean = rod.data([0.5, 20.0])
    sigma = 0.02 * float(np.abs(clean).mean())
    rng = np.random.default_rng(0)
    for _ in range(12):  # the 12th data set of the coverage study's stream
        v = clean + sigma * rng.normal(size=clean.size)
    res = fit(SteadyProblem(rod.system, rod.M_obs, v), [0.5, 20.0],
              formulation="ecfm-random", sigma=sigma)  # fmt: skip
    assert res.success and res.extra["tau"] > 0 and res.interval_likelihood is not None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        summary = profile_likelihood(res)
    assert "did not end at its optimum" not in summary.message
    assert summary.intervals[0, 0] == -np.inf and np.isfinite(summary.intervals[0, 1])
    assert summary.intervals[1, 0] < res.eps[1] < summary.intervals[1, 1]


def test_an_estimate_run_off_to_a_vanishing_reaction_rate_is_not_converged():
    """Data sets 17 and 26 of the same stream: the likelihood keeps falling as the rate
    10^eps0 -> 0, the standard fit says so (not converged); the random-force fit stopped
    there on a small gradient and used to report CONVERGED at eps0 = -14.7 (tau > 0) and
    -2.6e8 (tau = 0, the standard estimate)."""
    rod = ReactionRod(4)
    clean = rod.data([0.5, 20.0])
    sigma = 0.02 * float(np.abs(clean).mean())
    rng = np.random.default_rng(0)
    data = [clean + sigma * rng.normal(size=clean.size) for _ in range(27)]
    for k in (17, 26):
        res = fit(SteadyProblem(rod.system, rod.M_obs, data[k]), [0.5, 20.0],
                  formulation="ecfm-random", sigma=sigma)  # fmt: skip
        std = res.extra["standard"]  # the standard fit's Outcome: what it measured
        assert res.eps[0] < -10 and not holds(std.opt, std.failure)
        assert not res.success and "infinity" in res.message, (k, res.message)
