"""``sigma`` one per observation or a covariance for the Galerkin problems (issue: "for
every problem type"), against independent computations: the same model written as a
:class:`ModelProblem` (whose whitening is tested against scipy), scipy's ``curve_fit``
with ``absolute_sigma=True``, and the user whitening sensor matrix and data by hand
(``W M_obs``, ``W v``) with ``sigma=1``; the scalar path (older code) for an array of
equal values; refusals by their message."""

import numpy as np
import pytest
from scipy import optimize

from ecfm_uq.inverse import (
    DynamicInverseProblem,
    ModelProblem,
    ReplicatedProblem,
    SteadyProblem,
    fit,
    profile_intervals,
)
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)
TRUE = np.array([1.5, 2.0])
EPS0 = [1.0, 1.0]
#: heteroscedastic: the noise grows along the rod
S = 0.01 + 0.05 * SENS


def reaction_diffusion():
    """-10^-eps0 w'' + w = eps1 (1 + x) on (0, 1): eps0 acts nonlinearly (the shape)."""
    return GalerkinSystem(
        [
            LinearTerm(stiffness(B), Coefficient.power10(0)),
            LinearTerm(mass(B)),
            LoadTerm.scaled(load(B, lambda x: 1 + x), Coefficient.parameter(1)),
        ],
        2,
        Gamma=hat_forces(B, SENS, 0.1),
    )


SYSTEM = reaction_diffusion()
V0 = M_OBS @ solve_steady(SYSTEM, TRUE).Theta[:, 0]


def predict(eps):
    return M_OBS @ solve_steady(SYSTEM, eps).Theta[:, 0]


def covariance(C, seed, scale):
    Q = np.random.default_rng(seed).standard_normal((C, C))
    return scale * (Q @ Q.T / C + np.eye(C))


@pytest.fixture(scope="module")
def hetero():
    v = V0 + S * np.random.default_rng(1).standard_normal(S.size)
    return v, fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, sigma=S)


def test_steady_per_observation_sigma_equals_a_model_problem_and_curve_fit(hetero):
    v, res = hetero
    assert res.success, res.message
    mp = fit(ModelProblem(predict, v, jac="3-point"), EPS0, sigma=S)
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-3)
    assert res.uncertainty.noise_model == "known" and res.uncertainty.dof is None
    assert res.verdict.test == "chi2" and res.verdict.details["dof"] == S.size - 2
    assert res.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    e = (v - predict(res.eps)) / S
    assert res.verdict.details["chi2"] == pytest.approx(e @ e, rel=1e-9)

    # d eps/dv in the data's units: Gauss-Newton's J^+ W as the ModelProblem's, and the
    # exact one (implicit, full Hessian) against refits at perturbed data
    np.testing.assert_allclose(res.uncertainty.jacobian, mp.uncertainty.jacobian, rtol=1e-6)
    exact = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, sigma=S, options={"covariance": "sandwich"})
    h = 1e-3  # refits to round-off: a difference quotient of the estimate, O(h^2)

    def refit(w):
        return fit(SteadyProblem(SYSTEM, M_OBS, w), res.eps, sigma=S, tol=1e-12).eps

    quotients = [(refit(v + h * d) - refit(v - h * d)) / (2 * h) for d in np.eye(S.size)]
    np.testing.assert_allclose(exact.uncertainty.jacobian, np.transpose(quotients), rtol=1e-4)

    popt, pcov = optimize.curve_fit(
        lambda x, a, b: predict(np.array([a, b])), SENS, v, p0=EPS0, sigma=S,
        absolute_sigma=True, epsfcn=1e-12,
    )  # fmt: skip
    np.testing.assert_allclose(res.eps, popt, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, np.sqrt(np.diag(pcov)), rtol=1e-3)


def test_the_all_at_once_standard_fit_follows_and_says_the_noise_is_whitened(hetero):
    v, res = hetero
    slsqp = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, sigma=S, method="all-at-once")
    assert slsqp.success, slsqp.message
    np.testing.assert_allclose(slsqp.eps, res.eps, rtol=1e-6)
    np.testing.assert_allclose(slsqp.uncertainty.stderr, res.uncertainty.stderr, rtol=1e-6)
    # its verdict is the paper's moment test, on the whitened discrepancy
    assert "sigma=1 (whitened: sigma per observation (0.015 to 0.055))" in slsqp.verdict.message


# the profile and delta-method intervals of eps1 differ by a few percent here (warned)
@pytest.mark.filterwarnings("ignore:eps.*disagree")
def test_steady_covariance_equals_whitening_by_hand_with_sigma_one():
    Sig = covariance(9, 2, 1e-3)
    L = np.linalg.cholesky(Sig)
    W = np.linalg.inv(L)
    v = V0 + L @ np.random.default_rng(3).standard_normal(9)
    res = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, sigma=Sig)
    hand = fit(SteadyProblem(SYSTEM, W @ M_OBS, W @ v), EPS0, sigma=1.0)
    assert res.success and hand.success
    np.testing.assert_allclose(res.eps, hand.eps, rtol=1e-9)
    np.testing.assert_allclose(res.uncertainty.cov, hand.uncertainty.cov, rtol=1e-8)
    assert res.verdict.details["chi2"] == pytest.approx(hand.verdict.details["chi2"], rel=1e-9)
    assert res.verdict.p_value == pytest.approx(hand.verdict.p_value, rel=1e-8)
    # the estimate's derivative in the data given (v, not W v)
    np.testing.assert_allclose(res.uncertainty.jacobian, hand.uncertainty.jacobian @ W, rtol=1e-8)
    # the profile likelihood follows the whitening
    np.testing.assert_allclose(profile_intervals(res), profile_intervals(hand), rtol=1e-6)
    assert "covariance" in res.likelihood.description
    # the full-Hessian (sandwich) covariance follows too
    kw = {"options": {"covariance": "sandwich"}}
    sw = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, sigma=Sig, **kw)
    sw_hand = fit(SteadyProblem(SYSTEM, W @ M_OBS, W @ v), EPS0, sigma=1.0, **kw)
    assert sw.uncertainty.method == "implicit"
    np.testing.assert_allclose(sw.uncertainty.cov, sw_hand.uncertainty.cov, rtol=1e-7)


def test_steady_ecfm_estimate_ignores_sigma_its_uncertainty_and_verdict_follow_it():
    """The exact-match ECFM matches W M theta = W v, the same constraint as M theta = v:
    the estimate is the one without sigma; sigma enters the covariance (delta method with
    the data covariance) and the chi2 verdict on the whitened unforced residual."""
    Sig = covariance(9, 4, 1e-3)
    L = np.linalg.cholesky(Sig)
    W = np.linalg.inv(L)
    v = V0 + L @ np.random.default_rng(5).standard_normal(9)
    res = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, formulation="ecfm", sigma=Sig)
    plain = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, formulation="ecfm")
    hand = fit(SteadyProblem(SYSTEM, W @ M_OBS, W @ v), EPS0, formulation="ecfm", sigma=1.0)
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, plain.eps, rtol=1e-7)
    np.testing.assert_allclose(res.forces, plain.forces, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(res.uncertainty.cov, hand.uncertainty.cov, rtol=1e-6)
    # delta method by hand: d eps / dv of the ECFM estimate (from the fit without sigma,
    # in data units) with the data covariance Sigma
    D = res.uncertainty.jacobian
    np.testing.assert_allclose(res.uncertainty.cov, D @ Sig @ D.T, rtol=1e-10)
    e = W @ (v - predict(res.eps))
    assert res.verdict.test == "chi2"
    assert res.verdict.details["chi2"] == pytest.approx(e @ e, rel=1e-6)


def test_random_force_ecfm_with_equal_sigmas_is_the_scalar_fit():
    """Sigma + tau^2 A A^T by whitening: with sigma_i all equal it is the scalar code."""
    v = V0 + 0.01 * np.random.default_rng(6).standard_normal(9) + 0.05 * np.sin(7 * SENS)
    p = SteadyProblem(SYSTEM, M_OBS, v)
    arr = fit(p, EPS0, formulation="ecfm-random", sigma=np.full(9, 0.01))
    one = fit(p, EPS0, formulation="ecfm-random", sigma=0.01)
    assert arr.success and one.success
    np.testing.assert_allclose(arr.eps, one.eps, rtol=1e-6)
    # central differences of the profiled likelihood (steps in its own units)
    np.testing.assert_allclose(arr.uncertainty.stderr, one.uncertainty.stderr, rtol=2e-3)
    assert arr.verdict.p_value == pytest.approx(one.verdict.p_value)
    np.testing.assert_allclose(arr.forces, one.forces, rtol=1e-4, atol=1e-8)


def test_random_force_ecfm_likelihood_is_that_of_sigma_plus_forces():
    """At the estimate the conditional likelihood is r^T (Sigma + A G A^T)^-1 r / 2 with
    A = M dtheta/dlam computed here, the data covariance Sigma given as a matrix."""
    Sig = covariance(9, 7, 1e-4)
    v = V0 + np.linalg.cholesky(Sig) @ np.random.default_rng(8).standard_normal(9)
    v = v + 0.05 * np.sin(7 * SENS)
    res = fit(SteadyProblem(SYSTEM, M_OBS, v), EPS0, formulation="ecfm-random", sigma=Sig)
    assert res.success, res.message
    tau = res.extra["tau"]
    assert tau > 0
    sol = solve_steady(SYSTEM, res.eps)
    A = M_OBS @ sol.lam_sensitivity()[:, 0, :]
    r = v - M_OBS @ sol.Theta[:, 0]
    S_data = Sig + tau**2 * A @ A.T
    assert res.likelihood.value(res.eps) == pytest.approx(
        0.5 * r @ np.linalg.solve(S_data, r), rel=1e-6
    )


# -- a time series: sigma describes the sensors, the same at every time (per reading:
# -- tests/inverse/test_dynamic_reading_sigma.py) ----------------------------------------


@pytest.fixture(scope="module")
def burgers():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=12, n_steps=20, T=1.0, newton_tol=1e-12)
    return m, m.true_data([1.75, 1.0])


def _dynamic(m, M_obs, V):
    return DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, M_obs, V, solve_tol=1e-12)


def test_dynamic_sigma_per_sensor_equals_a_model_problem_of_the_readings(burgers):
    m, V0 = burgers
    s = np.array([0.01, 0.02, 0.03, 0.05])
    V = V0 + s * np.random.default_rng(3).standard_normal(V0.shape)
    p = _dynamic(m, m.M_obs, V)
    res = fit(p, [1.5, 0.5], sigma=s)
    assert res.success, res.message

    def readings(eps):
        return p.predictions(p.solve(eps))[1:]

    mp = fit(ModelProblem(readings, V[1:], jac="3-point"), [1.5, 0.5], sigma=np.tile(s, m.n_steps))
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-3)
    assert res.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    assert res.verdict.details["dof"] == m.n_steps * 4 - 2


def test_dynamic_sensor_covariance_equals_whitening_by_hand(burgers):
    m, V0 = burgers
    Sig = covariance(4, 9, 1e-4)
    L = np.linalg.cholesky(Sig)
    W = np.linalg.inv(L)
    V = V0 + (L @ np.random.default_rng(10).standard_normal((4, V0.shape[0]))).T
    for formulation in ("standard", "ecfm"):
        res = fit(_dynamic(m, m.M_obs, V), [1.5, 0.5], formulation=formulation, sigma=Sig)
        hand = fit(_dynamic(m, W @ m.M_obs, V @ W.T), [1.5, 0.5], formulation=formulation,
                   sigma=1.0)  # fmt: skip
        assert res.success and hand.success, res.message
        np.testing.assert_allclose(res.eps, hand.eps, rtol=1e-8)
        np.testing.assert_allclose(res.uncertainty.cov, hand.uncertainty.cov, rtol=1e-6)
        assert res.verdict.details["chi2"] == pytest.approx(hand.verdict.details["chi2"], rel=1e-8)
        if formulation == "standard":  # the profile likelihood follows
            np.testing.assert_allclose(profile_intervals(res), profile_intervals(hand), rtol=1e-8)
    # independent: the readings' covariance kron(I, Sigma) given to a ModelProblem
    p = _dynamic(m, m.M_obs, V)
    std = fit(p, [1.5, 0.5], sigma=Sig)
    mp = fit(
        ModelProblem(lambda e: p.predictions(p.solve(e))[1:], V[1:], jac="3-point"),
        [1.5, 0.5], sigma=np.kron(np.eye(m.n_steps), Sig),
    )  # fmt: skip
    np.testing.assert_allclose(std.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(std.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-3)
    assert std.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    assert "covariance" in p.log_likelihood("standard", Sig).description


# -- refusals, before any model solve ----------------------------------------------------


def test_formulations_without_a_whitened_form_refuse_an_array_sigma_by_name(burgers):
    p = SteadyProblem(SYSTEM, M_OBS, V0)
    with pytest.raises(ValueError, match=r"formulation='noisy-ecfm' takes `sigma` as one num"):
        fit(p, EPS0, formulation="noisy-ecfm", sigma=S)
    with pytest.raises(ValueError, match=r"ecfm-random.*or whiten"):
        fit(p, EPS0, formulation="noisy-ecfm", sigma=np.diag(S**2))
    from ecfm_uq.problems.beam import BeamModel

    beam = BeamModel()
    rep = ReplicatedProblem(
        beam.system, beam.M_obs, beam.sample_data(1.0, 5, rng=np.random.default_rng(0))
    )
    for given in (np.ones(beam.M_obs.shape[0]), 0.1):  # an array, and a number: not ignored
        with pytest.raises(ValueError, match="ReplicatedProblem.*estimated from the replicates"):
            fit(rep, [0.5], sigma=given)
    m, VB = burgers
    dyn = _dynamic(m, m.M_obs, VB)
    # a sigma per reading (n_steps, C) is taken: tests/inverse/test_dynamic_reading_sigma.py
    with pytest.raises(
        ValueError,
        match=r"`sigma`.*\(4,\) one standard deviation per sensor"
        r".*\(4, 4\).*\(20, 4\) one standard deviation per reading",
    ):
        fit(dyn, [1.5, 0.5], sigma=np.full(3, 0.01))


def test_a_malformed_array_sigma_is_named_with_the_shapes_it_may_take():
    p = SteadyProblem(SYSTEM, M_OBS, V0)
    with pytest.raises(ValueError, match=r"9 positive standard deviations.*\(9, 9\)"):
        fit(p, EPS0, sigma=np.ones(8))
    with pytest.raises(ValueError, match="entry 3"):
        fit(p, EPS0, sigma=np.where(np.arange(9) == 3, 0.0, 1.0))
    with pytest.raises(ValueError, match="not positive definite"):
        fit(p, EPS0, sigma=np.ones((9, 9)))
    with pytest.raises(ValueError, match="not symmetric"):
        fit(p, EPS0, sigma=np.eye(9) + np.eye(9, k=1) * 0.1)
