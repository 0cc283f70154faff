"""Delta-method covariance against a refit Jacobian and Gauss-Newton (linear case)."""

import numpy as np
import pytest

from ecfm_uq.inverse.statistics.uncertainty import (
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


def test_steady_standard_covariance_is_gauss_newton():
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v0, true, J = _heat_case()
    v = v0 + 0.01 * np.random.default_rng(0).normal(size=v0.size)
    res = fit(SteadyProblem(system, M_obs, v), [1.0, 1.0], sigma=0.01)
    assert res.success and res.uncertainty.noise_model == "known"
    np.testing.assert_allclose(res.uncertainty.cov, gauss_newton_covariance(J, 1e-4), rtol=1e-5)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_steady_covariance_equals_refit_jacobian(formulation):
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v0, true, _ = _heat_case()
    v = v0 + 0.01 * np.random.default_rng(1).normal(size=v0.size)
    kw = {"formulation": formulation}
    res = fit(SteadyProblem(system, M_obs, v), [1.0, 1.0], sigma=0.01, **kw)
    h = 1e-3
    cols = []
    for e in np.eye(v.size):
        ep = fit(SteadyProblem(system, M_obs, v + h * e), res.eps, **kw).eps
        em = fit(SteadyProblem(system, M_obs, v - h * e), res.eps, **kw).eps
        cols.append((ep - em) / (2 * h))
    D = np.column_stack(cols)
    np.testing.assert_allclose(res.uncertainty.cov, 1e-4 * D @ D.T, rtol=1e-5)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_steady_coverage_with_known_sigma_is_nominal(formulation):
    from ecfm_uq.inverse.coverage import steady_coverage

    system, M_obs, _, true, _ = _heat_case()
    r = steady_coverage(system, M_obs, true, 0.01, 200, 0, formulation, known_sigma=True)
    assert r["n_failed"] == 0
    assert 0.92 <= r["coverage"] <= 0.98, r


# --------------------------------------------------------------------------------------
# the other fits: the same implicit path, checked against refits at perturbed data
# --------------------------------------------------------------------------------------
def _fd4(fit, v, h):
    """Fourth-order central differences of eps_hat(v), column by column."""
    cols = []
    for i in range(v.size):
        e = np.zeros_like(v)
        e.flat[i] = h

        def f(t, e=e):
            return fit(v + t * e)

        cols.append((8 * (f(1) - f(-1)) - (f(2) - f(-2))) / (12 * h))
    return np.column_stack(cols)


def _misspecified_linear():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_inverse_noisy import SIGMA, _linear_1d

    from ecfm_uq.spectral import SineBasis, gram

    system, K, _, M_obs = _linear_1d()
    true_F = gram(SineBasis(8), SineBasis(5)) @ np.array([1.0, -0.5, 0.3, 0.0, 30.0])
    v0 = M_obs @ np.linalg.solve(K, true_F)
    return system, M_obs, v0 + SIGMA * np.random.default_rng(11).standard_normal(v0.size), SIGMA


def test_standard_slsqp_covariance_equals_refit_jacobian():
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v, sigma = _misspecified_linear()
    res = fit(
        SteadyProblem(system, M_obs, v), np.zeros(system.n_eps), method="all-at-once", sigma=sigma
    )
    assert res.uncertainty.noise_model == "known" and res.verdict is not None

    def refit(w):
        return fit(SteadyProblem(system, M_obs, w), res.eps, method="all-at-once", tol=1e-16).eps

    # the model is linear in eps, so eps_hat(v) is linear: a unit step has no truncation
    D = np.column_stack([(refit(v + e) - refit(v - e)) / 2 for e in np.eye(v.size)])
    cov_fd = sigma**2 * D @ D.T
    assert np.abs(res.uncertainty.cov - cov_fd).max() <= 1e-5 * np.abs(cov_fd).max()


def test_noisy_ecfm_covariance_equals_refit_jacobian():
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v, sigma = _misspecified_linear()
    res = fit(
        SteadyProblem(system, M_obs, v),
        np.zeros(system.n_eps),
        formulation="noisy-ecfm",
        sigma=sigma,
    )
    assert res.success and res.uncertainty.cov is not None, res.uncertainty.message
    # the data enter through the active moment bounds (here the lower mean bound and the
    # upper variance bound); the refits stay on the same active set
    assert np.sum(np.abs(res.extra["inequality"]) < 1e-8) == 2

    def refit(w):
        return fit(
            SteadyProblem(system, M_obs, w),
            res.eps,
            formulation="noisy-ecfm",
            sigma=sigma,
            options={"theta0": res.state, "ftol": 1e-16},
        ).eps

    D = _fd4(refit, v, 3e-2)  # SLSQP resolves eps to ~1e-9: a large step, O(h^4) stencil
    cov_fd = sigma**2 * D @ D.T
    assert np.abs(res.uncertainty.cov - cov_fd).max() <= 1e-5 * np.abs(cov_fd).max()


def _beam_data():
    from ecfm_uq.problems.beam import BeamModel

    m = BeamModel(n_basis=6, order=5)
    return m, m.sample_data(1.0, 25, rng=0), [(0.0, 0.99 * m.beta_min)]


def _with_statistics(v, i, dmean, dm):
    """Data whose sensor-i mean moves by dmean and centred second moment by dm (the
    other statistics unchanged)."""
    out = v.copy()
    dev = v[i] - v[i].mean()
    m = np.mean(dev**2)
    out[i] = v[i].mean() + dmean + dev * np.sqrt((m + dm) / m)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("formulation", ["standard", "inner-outer"])
def test_pseudo_likelihood_covariance_equals_refit_jacobian(formulation):
    from ecfm_uq.inverse import ReplicatedProblem, fit
    from ecfm_uq.inverse.problems.moments import replicate_statistics

    m, v, bounds = _beam_data()
    res = fit(
        ReplicatedProblem(m.system, m.M_obs, v), [0.5], formulation=formulation, bounds=bounds
    )
    assert res.success and res.uncertainty.noise_model == "replicates", res.uncertainty.message
    w, Sigma_w = replicate_statistics(v)
    C = v.shape[0]
    # refit at data with one statistic moved (4-point stencil); a tight inner solve so
    # the refits resolve the estimate far below the step. The step (relative): the
    # standard refits scatter by ~1e-9 in eps, which over 5e-4 made this reference noisy
    # at 3e-5 relative (round-off-level changes of the model moved it across rtol); at
    # 2e-3 it agrees to 2e-9 (4e-3: 6e-10). The inner-outer estimate is curved in the
    # statistics instead: its stencil error grows with the step (1e-6 at 2.5e-4, 3e-6 at
    # 5e-4, 3e-5 at 1e-3)
    step = {"standard": 2e-3, "inner-outer": 5e-4}[formulation]
    # "standard" has no inner force solve, hence no inner_tol
    inner = {"inner_tol": 1e-24} if formulation == "inner-outer" else None
    cols = []
    for k in range(2 * C):
        h = step * max(abs(w[k]), 1.0)

        def f(t, k=k, h=h):
            a = (t * h, 0.0) if k < C else (0.0, t * h)
            data = _with_statistics(v, k % C, *a)
            return fit(
                ReplicatedProblem(m.system, m.M_obs, data),
                res.eps,
                formulation=formulation,
                tol=1e-13,
                options=inner,
            ).eps

        cols.append((8 * (f(1) - f(-1)) - (f(2) - f(-2))) / (12 * h))
    D = np.column_stack(cols)
    np.testing.assert_allclose(res.uncertainty.cov, D @ Sigma_w @ D.T, rtol=1e-5)


def test_replicate_statistics_covariance_is_the_sample_covariance():
    from ecfm_uq.inverse.problems.moments import replicate_statistics

    rng = np.random.default_rng(4)
    v = rng.normal(size=(3, 400))
    w, S = replicate_statistics(v)
    np.testing.assert_allclose(w[:3], v.mean(axis=1))
    np.testing.assert_allclose(w[3:], v.var(axis=1))
    # the mean block is the textbook Cov(vbar) = S / D
    np.testing.assert_allclose(S[:3, :3], np.cov(v) / 400, rtol=1e-12)


# --------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("sigma", [0.0, -0.01, float("nan")])
def test_steady_fit_refuses_nonpositive_sigma_before_fitting(sigma, monkeypatch):
    import ecfm_uq.inverse.formulations.steady as steady
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v0, _, _ = _heat_case()

    def no_solve(*a, **k):
        raise AssertionError("a solve ran before sigma was checked")

    monkeypatch.setattr(steady, "solve_steady", no_solve)
    with pytest.raises(ValueError, match="sigma"):
        fit(SteadyProblem(system, M_obs, v0), [1.0, 1.0], sigma=sigma)


def test_fewer_sensors_than_parameters_is_refused():
    from ecfm_uq.inverse import SteadyProblem, fit

    system, M_obs, v0, _, _ = _heat_case()
    with pytest.raises(ValueError, match="fewer sensors than parameters"):
        fit(SteadyProblem(system, M_obs[:1], v0[:1]), [1.0, 1.0])


def _ratio_case():
    """Conductivity eps[0] and source eps[1]: theta = (eps[1]/eps[0]) K^-1 F, so only
    the ratio is identifiable; the free direction at (2, 1) is (2, 1)/sqrt(5)."""
    from ecfm_uq.spectral import SineBasis, load, sensor_matrix, stiffness
    from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

    B = SineBasis(8)
    F = load(B, np.ones_like)[:, None]
    system = GalerkinSystem(
        [
            LinearTerm(stiffness(B), Coefficient.parameter(0)),
            LoadTerm(
                lambda eps, t=None: eps[1] * F[:, 0], lambda eps, t=None: np.hstack([0 * F, F])
            ),
        ],
        2,
    )
    M_obs = sensor_matrix(B, np.linspace(0.1, 0.9, 5))
    v = M_obs @ solve_steady(system, [2.0, 1.0]).Theta[:, 0]
    return system, M_obs, v


def test_non_identifiable_combination_is_named_not_nan():
    from ecfm_uq.errors import NonIdentifiableError
    from ecfm_uq.inverse import SteadyProblem, fit
    from ecfm_uq.inverse.statistics.uncertainty import check_identifiable, gauss_newton_covariance

    system, M_obs, v = _ratio_case()
    res = fit(SteadyProblem(system, M_obs, v), [2.0, 1.0], sigma=0.01)
    assert res.uncertainty.cov is None and res.uncertainty.intervals is None
    # the null vector (2, 1)/sqrt(5) = (0.894, 0.447), named in the message
    assert "0.894*eps[0] + 0.447*eps[1]" in res.uncertainty.message, res.uncertainty.message
    with pytest.raises(NonIdentifiableError, match=r"0\.707\*eps\[0\] - 0\.707\*eps\[1\]"):
        check_identifiable([[1.0, 1.0], [1.0, 1.0]])
    with pytest.raises(NonIdentifiableError, match=r"parameter combination 1\*eps\[2\]"):
        gauss_newton_covariance(np.eye(4)[:, :3] * [1.0, 2.0, 0.0], 1.0)
