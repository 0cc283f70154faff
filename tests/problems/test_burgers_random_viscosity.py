"""Burgers with a random log-viscosity eps1(omega) = eps1 + delta (omega - 1/2), omega ~ U(0,1):
the same problem code as a stochastic Galerkin system (P > 1), checked against Monte Carlo
and Gauss quadrature over deterministic solves, and P = 1 against the deterministic model."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis, gauss_legendre
from ecfm_uq.problems.burgers import BurgersModel

SIZES = {"n_modes": 20, "n_steps": 40, "T": 1.0}
EPS = np.array([1.5, 1.0])
DELTA = 0.8


def _galerkin_sensor_moments(order):
    model = BurgersModel(viscosity_chaos=ChaosBasis(order), viscosity_spread=DELTA, **SIZES)
    Th = model.solve(EPS, strict=True).Theta[-1]
    mean = model.M_obs @ model.system.mean(Th)
    var = np.diag(model.M_obs @ model.system.covariance(Th) @ model.M_obs.T)
    return mean, var


def _deterministic_readings(omega):
    """Final-time sensor readings of deterministic solves at eps1(omega)."""
    det = BurgersModel(**SIZES)
    return np.array(
        [
            det.measure(det.solve([EPS[0] + DELTA * (o - 0.5), EPS[1]], strict=True))[-1]
            for o in omega
        ]
    )


@pytest.fixture(scope="module")
def pce4():
    return _galerkin_sensor_moments(4)


def test_pce_moments_agree_with_monte_carlo(pce4):
    rng = np.random.default_rng(20250)
    n = 300
    Y = _deterministic_readings(rng.uniform(size=n))
    mc_mean = Y.mean(axis=0)
    mc_var = Y.var(axis=0, ddof=1)
    se_mean = np.sqrt(mc_var / n)
    c = Y - mc_mean
    se_var = np.sqrt((np.mean(c**4, axis=0) - mc_var**2) / n)
    mean, var = pce4
    z_mean = (mean - mc_mean) / se_mean
    z_var = (var - mc_var) / se_var
    # 4 standard errors: a failure rate of 6e-5 per reading if the PCE were exact
    assert np.all(np.abs(z_mean) < 4.0), z_mean
    assert np.all(np.abs(z_var) < 4.0), z_var


def test_pce_moments_converge_to_gauss_quadrature(pce4):
    """Independent high-accuracy truth: 16-point Gauss-Legendre over omega."""
    x, w = gauss_legendre(16)
    Y = _deterministic_readings(np.ravel(x))
    ref_mean = w @ Y
    ref_var = w @ (Y - ref_mean) ** 2
    mean, var = pce4
    err4 = (
        np.abs(mean - ref_mean).max() / np.abs(ref_mean).max(),
        np.abs(var - ref_var).max() / np.abs(ref_var).max(),
    )
    mean6, var6 = _galerkin_sensor_moments(6)
    err6 = (
        np.abs(mean6 - ref_mean).max() / np.abs(ref_mean).max(),
        np.abs(var6 - ref_var).max() / np.abs(ref_var).max(),
    )
    assert max(err4) < 1e-3, err4
    assert max(err6) < 1e-5, err6
    assert err6[0] < err4[0] and err6[1] < err4[1]


def test_zero_order_chaos_equals_deterministic_solve():
    det = BurgersModel(**SIZES)
    p1 = BurgersModel(viscosity_chaos=ChaosBasis(0), **SIZES)
    assert p1.system.P == 1
    a = det.solve(EPS, sensitivities=True)
    b = p1.solve(EPS, sensitivities=True)
    np.testing.assert_allclose(b.Theta, a.Theta, rtol=0, atol=1e-13)
    np.testing.assert_allclose(b.dTheta, a.dTheta, rtol=0, atol=1e-12)
    V = det.measure(a)
    np.testing.assert_allclose(
        p1.solve((1.6, 0.9), data=V).lam, det.solve((1.6, 0.9), data=V).lam, rtol=0, atol=1e-11
    )


def test_zero_order_chaos_of_random_viscosity_is_the_mean_viscosity_model():
    # P = 1 projects nu(omega) onto its mean: E[10^(-delta (omega - 1/2))] in closed form
    mean_factor = (10 ** (DELTA / 2) - 10 ** (-DELTA / 2)) / (DELTA * np.log(10))
    p1 = BurgersModel(viscosity_chaos=ChaosBasis(0), viscosity_spread=DELTA, **SIZES)
    det = BurgersModel(**SIZES)
    eps_mean_nu = [EPS[0] - np.log10(mean_factor), EPS[1]]
    np.testing.assert_allclose(
        p1.solve(EPS).Theta[..., 0], det.solve(eps_mean_nu).Theta[..., 0], atol=1e-12
    )


def test_chaos_state_has_mean_initial_condition_only():
    model = BurgersModel(
        viscosity_chaos=ChaosBasis(3), viscosity_spread=DELTA, n_modes=6, n_steps=2
    )
    Th0 = model.Theta0
    assert Th0.shape == (6, 4)
    np.testing.assert_array_equal(Th0[:, 1:], 0.0)
    np.testing.assert_allclose(Th0[:, 0], model.theta0)
