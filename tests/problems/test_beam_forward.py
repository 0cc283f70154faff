"""Stochastic beam forward model (paper Section 3.3, Eqs. random_govern, pce, stats)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from ecfm_uq.chaos import gauss_legendre
from ecfm_uq.errors import SingularSystemError
from ecfm_uq.problems.beam import (
    BeamModel,
    BeamOperators,
    buckling_load,
    calibrate_delta,
)
from ecfm_uq.system import solve_steady


@pytest.fixture(scope="module")
def model():
    return BeamModel()


@pytest.fixture(scope="module")
def sol(model):
    s = model.solve(1.0)
    assert s.success
    return s


# -- operators against closed forms ---------------------------------------------------
def test_operators_closed_forms():
    H0, p = 1.7, 100.0
    ops = BeamOperators(6, H0=H0, p=p)
    k = np.pi * (2 * np.arange(1, 7) - 1) / 2
    # beam modes are orthogonal in f' and f'': K_G = diag(k^2/2), K0 = H0 diag(k^4/2)
    np.testing.assert_allclose(ops.KG, np.diag(k**2 / 2), atol=1e-11 * k.max() ** 2)
    np.testing.assert_allclose(ops.K0, H0 * np.diag(k**4 / 2), atol=1e-11 * k.max() ** 4)
    # F_i = p int sin(k x) = p (1 - cos k) / k = p / k
    np.testing.assert_allclose(ops.F, p / k, rtol=1e-13)
    # f_i'(1) = k cos(k) = 0: the boundary matrix vanishes up to round-off
    assert np.abs(ops.KBC).max() < 1e-10 * np.abs(ops.K0).max()


def test_softening_operator_against_adaptive_quadrature():
    ops = BeamOperators(4)
    k = ops.basis.wavenumbers
    for i, j in [(0, 0), (0, 2), (1, 3), (3, 3)]:
        f = lambda x, i=i, j=j: (
            (1 - 2 * abs(x - 0.5)) * k[i] ** 2 * np.sin(k[i] * x) * k[j] ** 2 * np.sin(k[j] * x)
        )
        ref = quad(f, 0, 0.5, epsabs=1e-13)[0] + quad(f, 0.5, 1, epsabs=1e-13)[0]
        assert ops.K1[i, j] == pytest.approx(ref, rel=1e-10, abs=1e-10)


# -- delta and buckling ---------------------------------------------------------------
def test_undamaged_buckling_load_is_euler():
    # f_1 = sin(pi x / 2) is the exact buckling mode of the uniform beam: beta = pi^2 H0 / 4
    assert buckling_load(0.0, omega=1.0, n_basis=15, H0=2.0) == pytest.approx(
        np.pi**2 / 2, rel=1e-12
    )


def test_calibrate_delta_hits_target_and_is_converged():
    delta = calibrate_delta(2.24)
    assert 0.17 < delta < 0.19  # SPEC: delta ~ 0.18
    assert buckling_load(delta, 1.0, n_basis=15) == pytest.approx(2.24, abs=1e-10)
    # Rayleigh-Ritz converges from above: a 40-mode model is within 1e-4 of the 15-mode one
    b40 = buckling_load(delta, 1.0, n_basis=40)
    assert 2.24 - 1e-4 < b40 <= 2.24 + 1e-12


def test_calibrate_delta_rejects_unreachable_target():
    with pytest.raises(ValueError, match="beta_crit"):
        calibrate_delta(3.0)
    with pytest.raises(ValueError, match="beta_crit"):
        calibrate_delta(-1.0)


def test_beta_crit_model(model):
    assert model.beta_crit(0.0) == pytest.approx(np.pi**2 / 4, rel=1e-12)
    # the 6-mode Ritz model is slightly stiffer than the 15-mode reference
    assert 2.24 <= model.beta_crit(1.0) < 2.2401
    assert model.beta_min == model.beta_crit(1.0)
    om = np.linspace(0, 1, 6)
    b = [model.beta_crit(w) for w in om]
    assert np.all(np.diff(b) < 0)  # softer with growing omega


@pytest.mark.parametrize("eps_shift", [0.0, 1e-9, 1.0])
def test_load_at_or_above_buckling_raises(model, eps_shift):
    eps = model.beta_crit(1.0) + eps_shift
    with pytest.raises(SingularSystemError, match=r"eps=.*beta_crit=2\.24"):
        model.solve(eps)
    with pytest.raises(SingularSystemError):
        model.response_function(eps)


def test_load_between_omega_bucklings(model):
    eps = 0.5 * (model.beta_crit(0.0) + model.beta_crit(1.0))
    # fine for the undamaged beam, but the PCE covers omega = 1 and must refuse
    assert np.all(np.isfinite(model.solve_deterministic(0.0, eps)))
    with pytest.raises(SingularSystemError, match="omega=1"):
        model.solve_deterministic(1.0, eps)
    with pytest.raises(SingularSystemError):
        model.solve(eps)


def test_just_below_buckling_solves(model):
    s = model.solve(model.beta_min - 1e-3)
    assert s.success


# -- the PCE --------------------------------------------------------------------------
@settings(max_examples=15, deadline=None)
@given(omega=st.floats(0.0, 1.0), eps=st.floats(-3.0, 2.2))
def test_deterministic_system_equals_plain_solve(omega, eps):
    # P = 1: the engine's deterministic system (basis=None) is the plain solve to round-off
    m = _MODEL
    s = solve_steady(m.system_at(omega), [eps], tol=1e-12, strict=True)
    assert s.Theta.shape == (m.N, 1)
    ref = m.solve_deterministic(omega, eps)
    np.testing.assert_allclose(s.Theta[:, 0], ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


_MODEL = BeamModel()


def test_pce_matches_15_mode_reference(model, sol):
    # paper Figure `comparison` (left): N = M = 6 PCE vs 15-mode deterministic solves
    x = np.linspace(0, 1, 101)
    for om in (0.0, 0.5, 1.0):
        w = model.displacement(sol.Theta, x, [om])[:, 0]
        u = model.deterministic_displacement(om, 1.0, x, n_basis=15)[:, 0]
        assert np.abs(w - u).max() / np.abs(u).max() < 1e-2


@pytest.mark.parametrize("order", [0, 2, 5])
def test_galerkin_equals_gauss_collocation(order):
    # For an operator affine in one germ, Galerkin order p equals interpolation at the
    # p + 1 Gauss nodes (the Galerkin equations are integrated exactly by that rule).
    m = BeamModel(order=order)
    Theta = m.solve(0.7, lam=[1.0, -2.0, 0.5, 0.0, 3.0]).Theta
    nodes, _ = gauss_legendre(order + 1)
    lam = np.array([1.0, -2.0, 0.5, 0.0, 3.0])
    for w in nodes:
        ref = m.solve_deterministic(w, 0.7, lam=lam)
        np.testing.assert_allclose(Theta @ m.chaos.evaluate([w])[0], ref, rtol=1e-11)


def test_pce_pointwise_convergence_with_order():
    om = np.linspace(0, 1, 11)
    errs = []
    for order in (1, 3, 5):
        m = BeamModel(order=order)
        Th = m.solve(1.0).Theta
        pce = m.sensor_samples(Th, om)
        ref = np.column_stack([m.M_obs @ m.solve_deterministic(w, 1.0) for w in om])
        errs.append(np.abs(pce - ref).max() / np.abs(ref).max())
    assert errs[0] > 30 * errs[1] > 900 * errs[2]


def test_stats_against_quadrature(model, sol):
    # Eq. stats against Gauss quadrature of the PCE samples themselves
    nodes, w = gauss_legendre(12)
    v = model.sensor_samples(sol.Theta, nodes)
    mu, var = model.sensor_moments(sol.Theta)
    np.testing.assert_allclose(mu, v @ w, rtol=1e-12)
    np.testing.assert_allclose(var, ((v - mu[:, None]) ** 2) @ w, rtol=1e-10)
    x = np.array([0.1, 0.5, 0.9])
    mu_x, var_x = model.displacement_moments(sol.Theta, x)
    vx = model.displacement(sol.Theta, x, nodes)
    np.testing.assert_allclose(mu_x, vx @ w, rtol=1e-12)
    np.testing.assert_allclose(var_x, ((vx - mu_x[:, None]) ** 2) @ w, rtol=1e-10)


def test_galerkin_moments_against_monte_carlo(model, sol):
    rng = np.random.default_rng(12345)
    om = rng.random(4000)
    f = model.response_function(1.0)
    v = np.array([f(w) for w in om])
    n = v.shape[0]
    mc_mu, mc_var = v.mean(0), v.var(0, ddof=1)
    se_mu = np.sqrt(mc_var / n)
    m4 = ((v - mc_mu) ** 4).mean(0)
    se_var = np.sqrt((m4 - mc_var**2) / n)
    mu, var = model.sensor_moments(sol.Theta)
    assert np.all(np.abs(mu - mc_mu) < 3 * se_mu)
    assert np.all(np.abs(var - mc_var) < 3 * se_var)


def test_response_function_matches_deterministic_solve(model):
    x = np.array([0.0, 0.33, 1.0])
    f = model.response_function(0.4, x=x)
    out = f(0.8)
    theta = model.solve_deterministic(0.8, 0.4)
    np.testing.assert_allclose(out[:5], model.M_obs @ theta, rtol=1e-13)
    np.testing.assert_allclose(out[5:], model.basis.evaluate(x) @ theta, rtol=1e-13, atol=1e-13)


# -- sensitivities (Eq. stochastic_sens) ---------------------------------------------
def test_eps_sensitivity_taylor(model):
    eps = 1.0
    dTheta, dlam = model.solve(eps).eps_sensitivity()
    assert dlam is None
    errs = []
    hs = [4e-2, 2e-2, 1e-2]
    for h in hs:
        fd = (model.solve(eps + h).Theta - model.solve(eps - h).Theta) / (2 * h)
        errs.append(np.abs(fd - dTheta[:, :, 0]).max())
    rates = np.log(np.array(errs[:-1]) / errs[1:]) / np.log(2)
    assert np.all(np.abs(rates - 2) < 0.1), rates


def test_lam_sensitivity_exact(model):
    # Theta is affine in lam, so a central difference is exact up to round-off
    lam0 = np.array([0.3, -1.0, 2.0, 0.0, 0.5])
    S = model.solve(1.0, lam=lam0).lam_sensitivity()
    assert S.shape == (model.N, model.P, 5)
    for j in range(5):
        e = np.zeros(5)
        e[j] = 0.5
        fd = (model.solve(1.0, lam=lam0 + e).Theta - model.solve(1.0, lam=lam0 - e).Theta) / 1.0
        np.testing.assert_allclose(S[:, :, j], fd, rtol=1e-9, atol=1e-9 * np.abs(fd).max())


# -- data ------------------------------------------------------------------------------
def test_sample_data(model, sol):
    v = model.sample_data(1.0, 25, rng=7)
    assert v.shape == (5, 25)
    om = np.random.default_rng(7).random(25)
    np.testing.assert_allclose(v, model.sensor_samples(sol.Theta, om), rtol=1e-12)
    # each replicate is a whole beam: one omega per column, all sensors moving together
    lo = model.sensor_samples(sol.Theta, [0.0])[:, 0]
    hi = model.sensor_samples(sol.Theta, [1.0])[:, 0]
    assert np.all((v >= lo[:, None] - 1e-9) & (v <= hi[:, None] + 1e-9))


def test_gaussian_forces_option():
    s = 0.04
    m = BeamModel(force_shape="gaussian", force_width=s)
    # int sin(k x) N(x; c, s^2) dx = sin(k c) exp(-k^2 s^2 / 2) (tails beyond [0, 1] ~ 1e-6)
    k = m.basis.wavenumbers[:, None]
    ref = np.sin(k * m.sensors[None, :4]) * np.exp(-(k**2) * s**2 / 2)
    np.testing.assert_allclose(m.Gamma[:, :4], ref, atol=1e-5)


# -- bad input -------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "exc", "word"),
    [
        ({"n_basis": 0}, ValueError, "n_basis"),
        ({"order": -1}, ValueError, "order"),
        ({"order": 2.5}, TypeError, "order"),
        ({"delta": 1.0}, ValueError, "delta"),
        ({"delta": float("nan")}, ValueError, "delta"),
        ({"H0": -1.0}, ValueError, "H0"),
        ({"sensors": [0.2, 1.5]}, ValueError, "points"),
        ({"sensors": [0.2, np.nan]}, ValueError, "sensors"),
        ({"force_shape": "box"}, ValueError, "force_shape"),
        ({"force_width": 0.0}, ValueError, "force_width"),
    ],
)
def test_bad_model_arguments(kwargs, exc, word):
    with pytest.raises(exc, match=word):
        BeamModel(**kwargs)


def test_bad_call_arguments(model, sol):
    with pytest.raises(ValueError, match="Theta"):
        model.displacement(sol.Theta[:, :3], [0.5], [0.5])
    with pytest.raises(ValueError, match="Theta"):
        model.sensor_moments(np.full((6, 6), np.nan))
    with pytest.raises(ValueError, match="x"):
        model.displacement(sol.Theta, [0.5, np.inf], [0.5])
    with pytest.raises(ValueError, match="x"):
        model.displacement(sol.Theta, [1.5], [0.5])
    with pytest.raises(ValueError, match="omega"):
        model.sensor_samples(sol.Theta, [1.2])
    with pytest.raises(ValueError, match="omega"):
        model.solve_deterministic(-0.1, 1.0)
    with pytest.raises(ValueError, match="eps"):
        model.solve(np.nan)
    with pytest.raises(ValueError, match="eps"):
        model.solve([1.0, 2.0])
    with pytest.raises(TypeError, match="eps"):
        model.solve("1")
    with pytest.raises(ValueError, match="lam"):
        model.solve(1.0, lam=[1.0, 2.0])
    with pytest.raises(ValueError, match="lam"):
        model.solve_deterministic(0.5, 1.0, n_basis=15, lam=np.zeros(5))
    with pytest.raises(ValueError, match="n_replicates"):
        model.sample_data(1.0, 0)
