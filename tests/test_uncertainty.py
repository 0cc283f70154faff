"""Delta-method covariance against a refit Jacobian and Gauss-Newton (linear case)."""

import numpy as np
import pytest

from ecfm_uq.inverse.uncertainty import (
    confidence_intervals,
    delta_method_covariance,
    estimate_jacobian,
    gauss_newton_covariance,
)


def _linear_case():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(12, 3))
    v = rng.normal(size=12)
    return J, v


def test_delta_equals_gauss_newton_linear():
    J, _ = _linear_case()
    sigma2 = 0.04
    # g(eps, v) = J^T (J eps - v): dg/deps = J^T J, dg/dv = -J^T
    D = estimate_jacobian(J.T @ J, -J.T)
    np.testing.assert_allclose(
        delta_method_covariance(D, sigma2), gauss_newton_covariance(J, sigma2), rtol=1e-10
    )


def test_delta_equals_refit_finite_differences():
    J, v = _linear_case()

    def refit(v):
        return np.linalg.lstsq(J, v, rcond=None)[0]

    h = 1e-6
    D_fd = np.column_stack(
        [(refit(v + h * e) - refit(v - h * e)) / (2 * h) for e in np.eye(v.size)]
    )
    Sigma = np.diag(np.linspace(0.01, 0.05, v.size))
    cov_fd = D_fd @ Sigma @ D_fd.T
    D = estimate_jacobian(J.T @ J, -J.T)
    np.testing.assert_allclose(delta_method_covariance(D, np.diag(Sigma)), cov_fd, rtol=1e-5)


def test_intervals_and_bad_input():
    se, ci = confidence_intervals([1.0], [[4.0]])
    assert se[0] == 2.0
    np.testing.assert_allclose(ci[0], [1 - 1.959964 * 2, 1 + 1.959964 * 2], rtol=1e-6)
    with pytest.raises(ValueError, match="level"):
        confidence_intervals([1.0], [[4.0]], level=1.5)
    with pytest.raises(ValueError, match="singular"):
        estimate_jacobian(np.zeros((2, 2)), np.ones((2, 3)))


def _heat_case():
    from ecfm_uq.spectral import SineBasis, hat_forces, load, sensor_matrix, stiffness
    from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

    B = SineBasis(12)
    F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
    sens = np.linspace(0.1, 0.9, 7)
    M_obs = sensor_matrix(B, sens)
    system = GalerkinSystem(
        [LinearTerm(stiffness(B), 1.0), LoadTerm.linear(F)], 2, Gamma=hat_forces(B, sens, 0.1)
    )
    true = np.array([3.0, -2.0])
    v0 = M_obs @ solve_steady(system, true).Theta[:, 0]
    J = M_obs @ np.column_stack(
        [
            solve_steady(system, true + e).Theta[:, 0] - solve_steady(system, true).Theta[:, 0]
            for e in np.eye(2)
        ]
    )  # exact: the model is linear in eps
    return system, M_obs, v0, true, J


def test_fit_steady_standard_covariance_is_gauss_newton():
    from ecfm_uq.inverse import fit_steady

    system, M_obs, v0, true, J = _heat_case()
    v = v0 + 0.01 * np.random.default_rng(0).normal(size=v0.size)
    res = fit_steady(system, M_obs, v, [1.0, 1.0], "standard", sigma=0.01)
    assert res.success and res.noise_model == "known"
    np.testing.assert_allclose(res.eps_cov, gauss_newton_covariance(J, 1e-4), rtol=1e-5)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_fit_steady_covariance_equals_refit_jacobian(formulation):
    from ecfm_uq.inverse import fit_steady

    system, M_obs, v0, true, _ = _heat_case()
    v = v0 + 0.01 * np.random.default_rng(1).normal(size=v0.size)
    res = fit_steady(system, M_obs, v, [1.0, 1.0], formulation, sigma=0.01)
    h = 1e-3
    cols = []
    for e in np.eye(v.size):
        ep = fit_steady(system, M_obs, v + h * e, res.eps, formulation).eps
        em = fit_steady(system, M_obs, v - h * e, res.eps, formulation).eps
        cols.append((ep - em) / (2 * h))
    D = np.column_stack(cols)
    np.testing.assert_allclose(res.eps_cov, 1e-4 * D @ D.T, rtol=1e-5)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_steady_coverage_with_known_sigma_is_nominal(formulation):
    from ecfm_uq.inverse.coverage import steady_coverage

    system, M_obs, _, true, _ = _heat_case()
    r = steady_coverage(system, M_obs, true, 0.01, 200, 0, formulation, known_sigma=True)
    assert r["n_failed"] == 0
    assert 0.92 <= r["coverage"] <= 0.98, r


# -- pseudo-likelihood estimates from replicated data (the beam) -----------------------
@pytest.fixture(scope="module")
def beam_data():
    from ecfm_uq.problems.beam import BeamModel

    model = BeamModel()
    v = model.sample_data(1.0, 25, rng=np.random.default_rng(4))
    return model, v, [(0.0, 0.99 * model.beta_min)]


@pytest.mark.parametrize("formulation", ["standard", "inner-outer"])
def test_likelihood_estimate_derivative_equals_refit_finite_differences(beam_data, formulation):
    from ecfm_uq.inverse import fit_pseudo_likelihood

    model, v, bounds = beam_data

    def fit(data):  # refits tight enough that a difference quotient resolves 1e-5
        return fit_pseudo_likelihood(
            model.system,
            model.M_obs,
            data,
            [1.0],
            formulation,
            bounds=bounds,
            gtol=1e-14,
            likelihood_options={"solve_options": {"tol": 1e-13}},
        )

    res = fit(v)
    assert res.success and res.noise_model == "replicates"
    D = res.extra["deps_dv"]
    assert D.shape == (1, 5, 25)
    h = 1e-2  # data are O(10): truncation error ~1e-8 relative, refit noise below it
    for i, j in [(0, 0), (2, 7), (4, 24)]:  # a few replicates, three sensors
        e = np.zeros_like(v)
        e[i, j] = h
        refit = (fit(v + e).eps[0] - fit(v - e).eps[0]) / (2 * h)
        np.testing.assert_allclose(D[0, i, j], refit, rtol=1e-5, atol=1e-7 * np.abs(D).max())
    assert res.eps_ci95[0, 0] < res.eps[0] < res.eps_ci95[0, 1]


def test_penalty_form_says_why_it_has_no_uncertainty(beam_data):
    from ecfm_uq.inverse import fit_pseudo_likelihood

    model, v, bounds = beam_data
    res = fit_pseudo_likelihood(
        model.system, model.M_obs, v, [0.5], "penalty", lam0=np.full(5, 1e-3), bounds=bounds
    )
    assert res.eps_cov is None and "no minimizer" in res.uncertainty_message
