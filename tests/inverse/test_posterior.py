"""emcee posterior of the standard Gaussian likelihood against the Laplace approximation."""

import numpy as np
import pytest

pytest.importorskip("emcee")

from ecfm_uq.inverse import SteadyProblem, fit  # noqa: E402
from ecfm_uq.inverse.statistics.posterior import sample_posterior  # noqa: E402


def _case():
    from ecfm_uq.spectral import SineBasis, load, sensor_matrix, stiffness
    from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

    B = SineBasis(10)
    F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
    M_obs = sensor_matrix(B, np.linspace(0.1, 0.9, 7))
    system = GalerkinSystem([LinearTerm(stiffness(B), 1.0), LoadTerm.linear(F)], 2)
    true = np.array([3.0, -2.0])
    v = M_obs @ solve_steady(system, true).Theta[:, 0]
    return system, M_obs, v + 0.01 * np.random.default_rng(0).normal(size=v.size)


@pytest.fixture(scope="module")
def runs():
    system, M_obs, v = _case()
    lap = fit(SteadyProblem(system, M_obs, v), [1.0, 1.0], sigma=0.01)
    with pytest.warns(DeprecationWarning, match=r"sample_posterior\(fit\(SteadyProblem"):
        post = sample_posterior(
            system,
            M_obs,
            v,
            0.01,
            lap.eps,
            bounds=[(-50, 50), (-50, 50)],
            n_walkers=16,
            n_steps=2500,
            seed=1,
        )
    return lap, post


def test_posterior_mean_and_cov_match_laplace_on_a_linear_model(runs):
    lap, post = runs
    assert post.converged, post.message
    sd = np.sqrt(np.diag(post.cov))
    # linear model, flat prior far from the data: the posterior IS the Laplace Gaussian
    assert np.all(np.abs(post.mean - lap.eps) < 0.1 * sd), (post.mean, lap.eps, sd)
    # covariance: sampling error of a variance is ~ sqrt(2/ESS)
    rel = np.sqrt(2 / post.ess.min())
    np.testing.assert_allclose(np.diag(post.cov), np.diag(lap.uncertainty.cov), rtol=4 * rel)


def test_diagnostics_and_refused_convergence(runs):
    _, post = runs
    assert np.all(post.tau > 1) and np.all(post.ess > 0)
    assert 0.1 < post.acceptance < 0.9
    assert post.chain.shape == (2500, 16, 2)
    system, M_obs, v = _case()
    with pytest.warns(DeprecationWarning, match="deprecated"):
        short = sample_posterior(
            system, M_obs, v, 0.01, runs[0].eps, bounds=[(-50, 50)] * 2, n_walkers=8, n_steps=60
        )
    assert not short.converged and "NOT converged" in short.message


@pytest.mark.filterwarnings("ignore:sample_posterior\\(system:DeprecationWarning")
def test_bad_input_is_refused():
    system, M_obs, v = _case()
    with pytest.raises(ValueError, match="prior"):
        sample_posterior(system, M_obs, v, 0.01, [3.0, -2.0], bounds=[(0, 1), (0, 1)])
    with pytest.raises(ValueError, match="prior"):
        sample_posterior(system, M_obs, v, 0.01, [3.0, -2.0], prior=lambda e: -np.inf)
    with pytest.raises(ValueError, match="sigma"):
        sample_posterior(system, M_obs, v, 0.0, [3.0, -2.0], bounds=[(-9, 9)] * 2)


def test_pair_plot(runs, tmp_path):
    from ecfm_uq.plotting import pair_plot, save_figure

    lap, post = runs
    fig = pair_plot(post.samples, laplace=(lap.eps, lap.uncertainty.cov), truth=[3.0, -2.0])
    save_figure(fig, tmp_path / "pair.png")
    assert (tmp_path / "pair.png").stat().st_size > 0


def test_posterior_of_a_random_force_ecfm_fit_is_its_laplace_approximation():
    """Missing source, tau > 0: the likelihood with the estimated discrepancy covariance
    S0 is Gaussian in the readings; near-linear in eps, its posterior under a wide flat
    prior is N(eps_hat, (J^T S0^-1 J)^-1)."""
    from ecfm_uq.inverse import SteadyProblem, fit
    from ecfm_uq.problems.reaction import ReactionRod

    rod = ReactionRod(9)
    clean = rod.data([1.5, 20.0], source=10.0)
    sigma = 0.002 * np.abs(clean).mean()
    v = clean + sigma * np.random.default_rng(3).standard_normal(clean.size)
    res = fit(SteadyProblem(rod.system, rod.M_obs, v), [1.0, 10.0],
              formulation="ecfm-random", sigma=sigma)  # fmt: skip
    assert res.extra["tau"] > 0 and not res.verdict.consistent
    post = sample_posterior(res, bounds=[(0.0, 3.0), (5.0, 40.0)], n_steps=3000, seed=1)
    assert post.success, post.message
    # Laplace covariance from the likelihood's exact gradient (central differences)
    ell = res.likelihood
    h = 1e-5 * np.maximum(1.0, np.abs(res.eps))
    H = np.column_stack(
        [(ell(res.eps + h[j] * e)[1] - ell(res.eps - h[j] * e)[1]) / (2 * h[j])
         for j, e in enumerate(np.eye(2))]
    )  # fmt: skip
    cov = np.linalg.inv(0.5 * (H + H.T))
    se = np.sqrt(np.diag(cov))
    # Monte Carlo error of the mean ~ se / sqrt(ess): allow 4 of those
    assert np.all(np.abs(post.mean - res.eps) < 4 * se / np.sqrt(post.ess) + 0.05 * se)
    np.testing.assert_allclose(np.sqrt(np.diag(post.cov)), se, rtol=0.15)


def test_posterior_of_a_dynamic_fit_and_refusals():
    from ecfm_uq.inverse import DynamicInverseProblem, SteadyProblem, fit
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=8, n_steps=10, T=0.5)
    V = m.true_data([1.75, 1.0])
    V = V + 1e-3 * np.random.default_rng(1).standard_normal(V.shape)
    dyn = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V)
    res = fit(dyn, [1.7, 0.9], sigma=1e-3, uncertainty=False)
    short = sample_posterior(res, bounds=[(1.0, 2.5), (0.5, 1.5)], n_steps=60, seed=0)
    assert not short.success and "NOT converged" in short.message
    assert short.nfev > 0 and np.all(np.abs(short.mean - res.eps) < 0.05)
    unknown = fit(dyn, [1.7, 0.9], uncertainty=False)  # sigma profiled: not a density
    with pytest.raises(ValueError, match="not a density"):
        sample_posterior(unknown, bounds=[(1.0, 2.5), (0.5, 1.5)])
    from ecfm_uq.problems.reaction import ReactionRod

    rod = ReactionRod(4)
    ecfm = fit(SteadyProblem(rod.system, rod.M_obs, rod.data([1.5, 20.0])), [1.0, 10.0],
               formulation="ecfm")  # fmt: skip
    with pytest.raises(ValueError, match="no likelihood"):
        sample_posterior(ecfm, bounds=[(0, 5), (0, 50)])
    with pytest.raises(TypeError, match="takes the data and sigma from the fit"):
        sample_posterior(res, m.M_obs, bounds=[(1.0, 2.5), (0.5, 1.5)])
