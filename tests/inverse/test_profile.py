"""Profile-likelihood intervals and likelihood-ratio tests (issue 20 item 1), checked
against closed forms (a model linear in its parameters, where the likelihood is exactly
quadratic), against a brute-force scan of the likelihood, and on a model with a
parameter inside the operator whose data do not bound it on one side."""

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.inverse import (
    DynamicInverseProblem,
    ReplicatedProblem,
    SteadyProblem,
    fit,
    likelihood_ratio_test,
    profile_intervals,
    profile_likelihood,
)
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
K = stiffness(B)
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)


def linear_model():
    """-w'' = eps0 + eps1 x: the readings are linear in eps, so the Gaussian
    log-likelihood is exactly quadratic and its profile intervals are closed forms."""
    F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
    system = GalerkinSystem([LinearTerm(K), LoadTerm.linear(F)], 2, Gamma=hat_forces(B, SENS, 0.1))
    J = np.column_stack([M_OBS @ solve_steady(system, e).Theta[:, 0] for e in np.eye(2)])
    return system, J


def reaction_model():
    """-w'' + 10**eps0 w = eps1: a reaction rate inside the operator."""
    terms = [
        LinearTerm(K),
        LinearTerm(mass(B), Coefficient.power10(0, sign=1.0)),
        LoadTerm.scaled(-load(B, np.ones_like), Coefficient.parameter(1)),
    ]
    return GalerkinSystem(terms, 2)


def noisy(v, sigma, seed):
    return v + sigma * np.random.default_rng(seed).standard_normal(v.shape)


@pytest.mark.parametrize("known_sigma", [True, False])
def test_linear_model_intervals_are_the_closed_form(known_sigma):
    system, J = linear_model()
    sigma = 0.01
    v = noisy(J @ [3.0, -2.0], sigma, 0)
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], sigma=sigma if known_sigma else None)
    eps_hat, rss_hat = np.linalg.lstsq(J, v, rcond=None)[:2]
    np.testing.assert_allclose(res.eps, eps_hat, rtol=1e-7)
    cii = np.diag(np.linalg.inv(J.T @ J))
    if known_sigma:  # 2 delta ell = (t - eps_hat)^2 / (sigma^2 c_ii) <= chi2_1
        half = np.sqrt(stats.chi2.ppf(0.95, 1) * sigma**2 * cii)
    else:  # profile-t: RSS(t) = RSS_hat + (t - eps_hat)^2 / c_ii <= RSS_hat (1 + F/(n-p)),
        # the Student-t interval t_{n-p} s sqrt(c_ii) of linear regression
        dof = v.size - 2
        half = stats.t.ppf(0.975, dof) * np.sqrt(rss_hat[0] / dof * cii)
    ci = profile_intervals(res, 0.95)
    np.testing.assert_allclose(ci, np.column_stack([eps_hat - half, eps_hat + half]), rtol=1e-6)
    summary = profile_likelihood(res, 0.95)
    # a linear model: the delta method is exact, on the same quantile, and agrees
    assert not summary.disagree.any(), summary.message
    np.testing.assert_allclose(summary.delta_intervals, ci, rtol=1e-6)
    assert res.uncertainty.dof == (None if known_sigma else v.size - 2)


def test_likelihood_ratio_test_is_the_closed_form_quadratic():
    system, J = linear_model()
    sigma = 0.01
    v = noisy(J @ [3.0, -2.0], sigma, 1)
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], sigma=sigma)
    d = np.array([0.02, -0.05])
    lr = likelihood_ratio_test(res, res.eps + d)
    stat = d @ (J.T @ J) @ d / sigma**2
    assert lr.dof == 2 and lr.statistic == pytest.approx(stat, rel=1e-6)
    assert lr.p_value == pytest.approx(stats.chi2.sf(stat, 2), rel=1e-6)
    # eps1 re-optimized: the profile statistic of eps0 alone, one degree of freedom
    one = likelihood_ratio_test(res, res.eps + d, free=[1])
    cii = np.linalg.inv(J.T @ J)[0, 0]
    assert one.dof == 1 and one.statistic == pytest.approx(d[0] ** 2 / (sigma**2 * cii), rel=1e-6)


def test_profile_matches_a_brute_force_scan_with_a_parameter_in_the_operator():
    system = reaction_model()
    M = sensor_matrix(B, np.linspace(0.15, 0.85, 6))
    v0 = M @ solve_steady(system, [1.5, 20.0]).Theta[:, 0]
    sigma = 0.02 * np.abs(v0).mean()
    problem = SteadyProblem(system, M, noisy(v0, sigma, 3))
    res = fit(problem, [1.0, 10.0], sigma=sigma)
    summary = profile_likelihood(res, 0.9, which=[0])
    lo, hi = summary.intervals[0]
    assert np.isnan(summary.intervals[1]).all()  # not profiled

    # independent: minimize over eps1 on a fine grid of eps0 by a scalar solver
    def ell(e0):
        def rss(e1):
            r = M @ solve_steady(system, [e0, e1]).Theta[:, 0] - problem.v
            return r @ r

        from scipy.optimize import minimize_scalar

        return minimize_scalar(rss, bracket=(res.eps[1] - 5, res.eps[1] + 5), tol=1e-12).fun

    target = ell(res.eps[0]) + sigma**2 * stats.chi2.ppf(0.9, 1)
    for end in (lo, hi):
        assert ell(end) == pytest.approx(target, rel=1e-6)
    assert lo < res.eps[0] < hi


def test_an_end_the_data_do_not_bound_is_the_bound_or_infinite_with_the_reason():
    """Tiny reaction: 10**eps0 -> 0 as eps0 -> -inf changes nothing the sensors see, so
    the profile flattens below the threshold on the left."""
    system = reaction_model()
    M = sensor_matrix(B, np.linspace(0.15, 0.85, 6))
    v0 = M @ solve_steady(system, [-2.0, 20.0]).Theta[:, 0]
    sigma = 0.02 * np.abs(v0).mean()
    problem = SteadyProblem(system, M, noisy(v0, sigma, 4))
    bounded = fit(problem, [-1.0, 10.0], sigma=sigma, bounds=[(-6.0, 4.0), (None, None)])
    summary = profile_likelihood(bounded, which=[0])
    assert summary.intervals[0, 0] == -6.0
    assert "do not bound" in summary.profiles[0].reasons[0]
    assert summary.disagree[0] and "eps[0] lower end open" in summary.message
    open_ = fit(problem, [-1.0, 10.0], sigma=sigma)
    summary = profile_likelihood(open_, which=[0], max_steps=15)
    assert summary.intervals[0, 0] == -np.inf and np.isfinite(summary.intervals[0, 1])
    with pytest.warns(UserWarning, match="disagree"):
        profile_intervals(open_, which=[0], max_steps=15)


def test_pseudo_likelihood_profile_is_calibrated_by_the_sandwich():
    """Replicated beam data: the Gaussian pseudo-likelihood treats the sensors as
    independent while one random stiffness moves them together, so its raw curvature
    overstates the information; the adjusted profile matches the sandwich interval."""
    from ecfm_uq.problems.beam import BeamModel

    beam = BeamModel()
    v = beam.sample_data(1.0, 25, rng=np.random.default_rng(0))
    res = fit(ReplicatedProblem(beam.system, beam.M_obs, v), [0.5], bounds=[(0.0, 2.0)])
    summary = profile_likelihood(res)
    (lo, hi), prof = summary.intervals[0], summary.profiles[0]
    assert not summary.disagree[0], summary.message
    np.testing.assert_allclose(summary.intervals, summary.delta_intervals, rtol=0.02)
    # one parameter: the profile is the pseudo-likelihood itself at the interval's ends
    ell = res.likelihood
    for end in (lo, hi):
        assert ell([end])[0] - ell(res.eps)[0] == pytest.approx(prof.threshold, rel=1e-6)
    assert prof.threshold > 0.5 * stats.chi2.ppf(0.95, 1)  # the raw curvature is too sharp
    lr = likelihood_ratio_test(res, [hi])
    assert lr.p_value == pytest.approx(0.05, rel=1e-4)


def test_dynamic_fit_profiles_cross_where_the_likelihood_ratio_test_says():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=8, n_steps=10, T=0.5)
    V = m.true_data([1.75, 1.0])
    V = V + 1e-3 * np.random.default_rng(1).standard_normal(V.shape)
    dyn = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V)
    res = fit(dyn, [1.7, 0.9], sigma=1e-3, uncertainty=False)
    summary = profile_likelihood(res, which=[1])
    lo, hi = summary.intervals[1]
    assert lo < res.eps[1] < hi and abs(hi - lo) < 0.1
    for end in (lo, hi):
        lr = likelihood_ratio_test(res, [res.eps[0], end], free=[0])
        assert lr.dof == 1 and lr.p_value == pytest.approx(0.05, rel=1e-3)


def test_results_without_a_likelihood_and_bad_levels_are_refused():
    system, J = linear_model()
    v = J @ [3.0, -2.0]
    ecfm = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation="ecfm")
    with pytest.raises(ValueError, match="`result` has no likelihood.*formulation='standard'"):
        profile_intervals(ecfm)
    res = fit(SteadyProblem(system, M_OBS, noisy(v, 0.01, 2)), [1.0, 1.0], sigma=0.01)
    for level in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match="`level` must be in"):
            profile_intervals(res, level)
    with pytest.raises(ValueError, match="`which`"):
        profile_intervals(res, which=[2])
    with pytest.raises(ValueError, match="sigma"):
        fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], sigma=-1.0)
