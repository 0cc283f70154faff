"""emcee posterior of the standard Gaussian likelihood against the Laplace approximation."""

import numpy as np
import pytest

pytest.importorskip("emcee")

from ecfm_uq.inverse import fit_steady  # noqa: E402
from ecfm_uq.inverse.posterior import sample_posterior  # noqa: E402


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
    lap = fit_steady(system, M_obs, v, [1.0, 1.0], "standard", sigma=0.01)
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
    np.testing.assert_allclose(np.diag(post.cov), np.diag(lap.eps_cov), rtol=4 * rel)


def test_diagnostics_and_refused_convergence(runs):
    _, post = runs
    assert np.all(post.tau > 1) and np.all(post.ess > 0)
    assert 0.1 < post.acceptance < 0.9
    assert post.chain.shape == (2500, 16, 2)
    system, M_obs, v = _case()
    short = sample_posterior(
        system, M_obs, v, 0.01, runs[0].eps, bounds=[(-50, 50)] * 2, n_walkers=8, n_steps=60
    )
    assert not short.converged and "NOT converged" in short.message


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
    fig = pair_plot(post.samples, laplace=(lap.eps, lap.eps_cov), truth=[3.0, -2.0])
    save_figure(fig, tmp_path / "pair.png")
    assert (tmp_path / "pair.png").stat().st_size > 0
