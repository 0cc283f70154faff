"""OdeProblem: a user's ODE fitted by least squares through forward sensitivities, against
scipy alone (solve_ivp inside least_squares), finite differences and the data rewritten."""

import numpy as np
import pytest
from scipy import optimize
from scipy.integrate import solve_ivp

from ecfm_uq.inverse import OdeProblem, fit, profile_likelihood
from ecfm_uq.problems.lotka_volterra import jac_eps as lv_jac_eps
from ecfm_uq.problems.lotka_volterra import jac_y as lv_jac_y
from ecfm_uq.problems.lotka_volterra import rhs as lv

TRUTH = np.array([0.5, 0.025, 0.025, 0.8, 30.0, 4.0])
T = np.arange(0.0, 16.0, 1.0)
RTOL = 1e-10


def y0_of(e):
    return e[4:6]


def truth_states(eps=TRUTH, t=T):
    sol = solve_ivp(lambda s, y: lv(s, y, eps), (0.0, t[-1]), eps[4:6], method="DOP853",
                    t_eval=t, rtol=1e-12, atol=1e-12)  # fmt: skip
    return sol.y.T


def noisy_data(seed=0, rel=0.03):
    Y = truth_states()
    rng = np.random.default_rng(seed)
    return Y * (1 + rel * rng.standard_normal(Y.shape))


def problem(data, t=T, **kw):
    kw.setdefault("jac", (lv_jac_y, lv_jac_eps))
    return OdeProblem(lv, y0_of, t, data, t0=0.0, rtol=RTOL, atol=1e-10, **kw)


def scipy_fit(data, t=T):
    mask = np.isfinite(data)

    def r(e):
        s = solve_ivp(lambda x, y: lv(x, y, e), (0.0, t[-1]), e[4:6], method="DOP853",
                      t_eval=t, rtol=RTOL, atol=1e-10)  # fmt: skip
        return (s.y.T - data)[mask]

    return optimize.least_squares(r, TRUTH * 1.05, jac="3-point", xtol=1e-15, ftol=1e-15,
                                  gtol=1e-15, x_scale="jac").x  # fmt: skip


def test_estimates_equal_scipy_least_squares_and_status_from_optimality():
    data = noisy_data()
    res = fit(problem(data), TRUTH * 1.05)
    assert res.success, res.message
    ref = scipy_fit(data)
    assert np.max(np.abs(res.eps / ref - 1)) < 1e-6
    assert res.optimality is not None
    assert res.uncertainty.success and np.all(res.uncertainty.stderr > 0)
    assert res.state.y.shape[1] == 2
    assert res.extra["prediction"].shape == data.shape


def test_differenced_sensitivities_give_the_same_estimate():
    data = noisy_data(1)
    a = fit(problem(data), TRUTH * 1.05)
    b = fit(problem(data, jac=None, vectorized=True), TRUTH * 1.05)
    assert a.success and b.success
    assert np.max(np.abs(a.eps / b.eps - 1)) < 1e-6


@pytest.mark.parametrize("mode", ["jac", "vectorized", "loop"])
def test_sensitivities_match_finite_differences(mode):
    kw = {"jac": {"jac": (lv_jac_y, lv_jac_eps)}, "vectorized": {"jac": None, "vectorized": True},
          "loop": {"jac": None, "vectorized": False}}[mode]  # fmt: skip
    pb = problem(noisy_data(), **kw)
    e = pb.check(TRUTH * 1.02)
    J = pb.predict_jacobian(e)
    F = np.empty_like(J)
    for j in range(e.size):
        h = 1e-5 * abs(e[j])
        ep, em = e.copy(), e.copy()
        ep[j] += h
        em[j] -= h
        F[:, j] = (pb.predict(ep) - pb.predict(em)) / (2 * h)
    scale = np.max(np.abs(F), axis=0)
    assert np.max(np.abs(J - F) / scale) < 1e-5


def test_vectorized_rhs_is_detected_and_a_scalar_one_falls_back():
    data = noisy_data()
    pb = problem(data, jac=None)
    pb.check(TRUTH)
    assert pb.vectorized  # lv takes columns

    def scalar_only(t, y, e):
        u, v = float(y[0]), float(y[1])
        return np.array([e[0] * u - e[1] * u * v, e[2] * u * v - e[3] * v])

    pb = OdeProblem(scalar_only, y0_of, T, data, t0=0.0)
    pb.check(TRUTH)
    assert not pb.vectorized
    with pytest.raises(ValueError, match="vectorized=True"):
        OdeProblem(scalar_only, y0_of, T, data, t0=0.0, vectorized=True).check(TRUTH)


def test_nan_readings_are_skipped_like_rows_removed():
    data = noisy_data(2)
    gap = data.copy()
    gap[[3, 7]] = np.nan
    res = fit(problem(gap), TRUTH * 1.05)
    keep = np.setdiff1d(np.arange(T.size), [3, 7])
    ref = fit(problem(data[keep], t=T[keep]), TRUTH * 1.05)
    assert res.success and ref.success
    assert np.max(np.abs(res.eps / ref.eps - 1)) < 1e-7
    assert res.extra["n_missing"] == 4
    assert "4 missing reading(s)" in res.summary()
    one = data.copy()
    one[5, 1] = np.nan  # one component of one reading
    pb = problem(one)
    assert pb.n_data == data.size - 1
    assert fit(pb, TRUTH * 1.05).success


def test_y0_of_eps_is_fitted_from_noise_free_data():
    res = fit(problem(truth_states()), TRUTH * 1.1)
    assert res.success
    np.testing.assert_allclose(res.eps, TRUTH, rtol=1e-6)


def test_observe_matrix_reads_combinations():
    H = np.array([[1.0, 1.0], [0.0, 2.0]])
    data = truth_states() @ H.T
    res = fit(problem(data, observe=H), TRUTH * 1.1)
    assert res.success
    np.testing.assert_allclose(res.eps, TRUTH, rtol=1e-6)
    lynx = OdeProblem(
        lv,
        TRUTH[4:6],
        T,
        truth_states()[:, [1]],
        t0=0.0,
        observe=[1],
        rtol=1e-9,
        jac=(lv_jac_y, lambda t, y, e: lv_jac_eps(t, y, e)[:, :4]),
    )
    one = fit(lynx, TRUTH[:4] * 1.02)  # the predator alone, initial state known
    assert one.success
    np.testing.assert_allclose(one.eps, TRUTH[:4], rtol=1e-5)


def test_sigma_per_reading_and_covariance_and_profile():
    data = noisy_data(3)
    data[4, 0] = np.nan
    s = np.full(data.shape, 0.5)
    s[4, 0] = np.nan
    res = fit(problem(data), TRUTH * 1.05, sigma=s)
    assert res.success and res.verdict.consistent is not None
    scalar = fit(problem(data), TRUTH * 1.05, sigma=0.5)
    np.testing.assert_allclose(res.uncertainty.stderr, scalar.uncertainty.stderr, rtol=1e-8)
    cov = fit(problem(data), TRUTH * 1.05, sigma=0.25 * np.eye(2))
    np.testing.assert_allclose(cov.uncertainty.stderr, scalar.uncertainty.stderr, rtol=1e-6)


def test_profile_likelihood_of_an_ode_fit():
    scalar = fit(problem(noisy_data(3)), TRUTH * 1.05, sigma=0.5)
    prof = profile_likelihood(scalar, which=[3])
    lo, hi = prof.intervals[3]
    assert lo < scalar.eps[3] < hi


def test_refusals_before_any_integration():
    calls = {"n": 0}

    def counted(t, y, e):
        calls["n"] += 1
        return lv(t, y, e)

    data = noisy_data()
    with pytest.raises(ValueError, match="strictly increasing"):
        OdeProblem(counted, [30, 4], T[::-1], data, t0=0.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        OdeProblem(counted, [30, 4], np.r_[T[:-1], T[-2]], data, t0=0.0)
    with pytest.raises(ValueError, match="after the first datum"):
        OdeProblem(counted, [30, 4], T, data, t0=0.5)
    with pytest.raises(ValueError, match="observe"):
        OdeProblem(counted, [30, 4], T, data, t0=0.0, observe=[0])
    with pytest.raises(ValueError, match="observe"):
        OdeProblem(counted, [30, 4], T, data, t0=0.0, observe=np.eye(3))
    with pytest.raises(ValueError, match="data"):
        OdeProblem(counted, [30, 4], T, data[:-1], t0=0.0)
    bad = OdeProblem(lambda t, y, e: np.zeros(3), [30, 4], T, data, t0=0.0)
    with pytest.raises(ValueError, match="rhs"):
        fit(bad, TRUTH[:4])
    wrong_y0 = OdeProblem(counted, lambda e: e[4:7], T, data, t0=0.0)
    with pytest.raises(ValueError, match="y0"):
        fit(wrong_y0, np.r_[TRUTH, 1.0])
    assert calls["n"] == 0  # refused before any integration
    with pytest.raises(ValueError, match="sigma"):
        fit(problem(data), TRUTH, sigma=np.ones((3, 3)))
