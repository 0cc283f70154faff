"""The exact-match ECFM of an OdeProblem: forces piecewise constant between data times,
against finite differences (their Jacobians), a known added force (the forces recovered
at any sampling density), the data themselves (exact match), and Monte Carlo (the false
alarm rate and the power of the forces' chi-squared test)."""

import matplotlib
import numpy as np
import pytest

from ecfm_uq.inverse import ForceSeries, OdeProblem, OdeTrajectory, fit
from ecfm_uq.inverse.core.fitter import Outcome
from ecfm_uq.inverse.formulations.ode_basis import BasisForces
from ecfm_uq.inverse.formulations.ode_forces import ExactForces, forced_components
from ecfm_uq.inverse.problems.force_bases import basis_matrix
from ecfm_uq.studies.ode import TRUTH as STUDY_TRUTH
from ecfm_uq.studies.ode import lv_problem as problem  # LV with its Jacobians
from ecfm_uq.studies.ode import simulate  # the data of `ecfm-uq reproduce ode`

matplotlib.use("Agg")

TRUTH = np.array(STUDY_TRUTH)


ANNUAL = np.arange(0.0, 13.0)


def _fd_of(fun, x, rel=1e-6):
    cols = []
    for j in range(x.size):
        h = rel * max(abs(x[j]), 1.0)
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        cols.append((fun(xp) - fun(xm)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("t0", [0.0, -0.5])  # a datum at t0 (initial jump) or not
@pytest.mark.parametrize("jac", ["exact", "differenced"])
def test_force_jacobians_match_finite_differences(t0, jac):
    times = ANNUAL if jac == "exact" else ANNUAL[:7]  # the differenced solves cost more
    data = simulate(times) * (1 + 0.02 * np.random.default_rng(0).standard_normal((times.size, 2)))
    data[4, 1] = np.nan
    kw = {} if jac == "exact" else {"jac": None, "vectorized": True}
    pb = problem(times, data, rtol=1e-11, t0=t0, **kw)
    e = pb.check(TRUTH * 1.03)
    ef = ExactForces(pb, forced_components(pb))
    out = ef.solve(e, with_data=True)
    F = _fd_of(lambda x: ExactForces(pb, ef.F).solve(x)["r"], e)
    scale = np.max(np.abs(F), axis=0)
    assert np.max(np.abs(out["J"] - F) / scale) < 1e-5
    d0, cols = pb.readings, [0, 5, 11]  # the first reading (the jump), a few later

    def of_data(d):
        full = pb.v.copy()
        full[pb.mask] = d
        return ExactForces(pb.with_data(full), ef.F).solve(e)["r"]

    G = np.column_stack([_fd_of(lambda x, k=k: of_data(np.r_[d0[:k], x, d0[k + 1 :]]),
                                d0[k : k + 1], rel=1e-5)[:, 0] for k in cols])  # fmt: skip
    assert np.max(np.abs(out["R_d"][:, cols] - G)) < 1e-5 * np.max(np.abs(G))
    # the missing lynx reading at t = 4: its force on [3, 4) is 0, free of the data
    row = 9  # after the jump's two rows and three intervals', or four intervals' rows
    assert out["r"][row] == 0.0 and np.all(out["J"][row] == 0.0)


@pytest.mark.parametrize("step", [1.0, 0.25])
def test_a_constant_added_force_is_recovered_at_any_sampling(step):
    times = np.arange(0.0, 6.0 + step / 2, step)
    push = np.array([1.5, -0.4])
    data = simulate(times, push=push)
    pb = problem(times, data, rtol=1e-11)
    e = pb.check(TRUTH)
    out = ExactForces(pb, forced_components(pb)).solve(e)
    np.testing.assert_allclose(out["forces"], np.tile(push, (times.size - 1, 1)), atol=1e-6)
    np.testing.assert_allclose(out["jump"], 0.0, atol=1e-9)


def test_noise_free_data_give_zero_forces_and_the_truth():
    data = simulate(ANNUAL)
    res = fit(problem(ANNUAL, data), TRUTH * 1.05, formulation="ecfm")
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, TRUTH, rtol=1e-5)
    assert np.max(np.abs(res.forces.values)) < 1e-5
    assert res.verdict.consistent is None and res.uncertainty.success is False


def test_forced_solution_meets_the_data_and_series_interface():
    data = simulate(ANNUAL, harvest=0.4) * (
        1 + 0.02 * np.random.default_rng(1).standard_normal((13, 2))
    )
    data[6, 0] = np.nan
    res = fit(
        problem(ANNUAL, data),
        TRUTH * 1.02,
        formulation="ecfm",
        sigma=0.02 * np.abs(simulate(ANNUAL)),
    )
    assert res.success, res.message
    f, state = res.forces, res.state
    assert isinstance(f, ForceSeries) and isinstance(state, OdeTrajectory)
    assert f.values.shape == (12, 2) and f.stderr.shape == (12, 2) and f.times.shape == (12,)
    np.testing.assert_array_equal(f.intervals[:, 1], ANNUAL[1:])
    assert f.names == ["hare", "lynx"] and state.names == ["hare", "lynx"]
    assert f.values[5, 0] == 0.0 and f.stderr[5, 0] == 0.0  # hare missing at t = 6
    Y = state(ANNUAL)
    ok = np.isfinite(data)
    np.testing.assert_allclose(Y[ok], data[ok], rtol=1e-6)
    ax = f.plot()
    assert ax.get_xlabel() == "t"
    assert res.uncertainty.success and res.verdict.consistent is not None
    assert res.extra["force_cov"].shape[0] == res.extra["force_cov"].shape[1]


def alarm_rates(times, R, rel, harvest, seed, rtol=1e-7):
    """Shares of R synthetic data sets (relative noise ``rel``, known) whose forces'
    chi-squared test rejects at alpha = 0.05, whose Bonferroni z-scores name the hare
    inside the harvest window, and whose fit did not converge."""
    rng = np.random.default_rng(seed)
    clean = simulate(times, harvest=harvest)
    sigma = rel * np.abs(clean)
    rejected = located = failed = 0
    for _ in range(R):
        data = clean + sigma * rng.standard_normal(clean.shape)
        res = fit(problem(times, data, rtol=rtol), TRUTH * 1.02, formulation="ecfm", sigma=sigma)
        failed += not res.success
        rejected += res.verdict.consistent is False
        located += any(n == "hare" and a >= 4.0 and b <= 9.0 for n, (a, b), _ in
                       res.extra["significant_forces"])  # fmt: skip
    return rejected / R, located / R, failed / R


def test_false_alarms_and_harvest_detection_small():
    """R = 4 on a cheap annual configuration (11 years, rtol 1e-5): at most one false
    alarm (binomial p = 0.014 for two or more at alpha = 0.05), the missing harvest
    flagged in every set."""
    times = ANNUAL[:11]
    false, _, failed = alarm_rates(times, 4, 0.03, 0.0, seed=1, rtol=1e-5)
    power, located, failed_h = alarm_rates(times, 4, 0.03, 0.6, seed=2, rtol=1e-5)
    assert failed == failed_h == 0
    assert false <= 1 / 4
    assert power == 1.0 and located >= 0.5


@pytest.mark.slow
@pytest.mark.parametrize(
    ("times", "seeds"),
    [(np.arange(0.0, 21.0), (10, 11)), (np.arange(0.0, 10.0 + 1e-9, 1 / 12), (20, 21))],
    ids=["annual", "monthly"],
)
def test_false_alarm_rate_and_power_study(times, seeds):
    """R = 100 data sets, 3 % noise: the test's size in [0.01, 0.10] on the correct
    model; a harvest du/dt -= 0.6 u on [5, 8) left out of the model flagged in >= 95 %."""
    false, _, failed = alarm_rates(times, 100, 0.03, 0.0, seed=seeds[0])
    power, located, failed_h = alarm_rates(times, 100, 0.03, 0.6, seed=seeds[1])
    print(f"false alarms {false:.2f}, power {power:.2f}, located {located:.2f}, not "
          f"converged {failed:.2f} / {failed_h:.2f}")  # fmt: skip
    assert failed <= 0.02 and failed_h <= 0.05
    assert 0.01 <= false <= 0.10
    assert power >= 0.95 and located >= 0.9


def test_extra_keys_documented_and_no_likelihood_for_profiles():
    import re

    from ecfm_uq.inverse import InverseResult, profile_likelihood

    doc = InverseResult.__doc__
    rows = "".join(doc[doc.index("extra : Details") :].split("=====")[2:-1])
    keys = {m for line in rows.splitlines() for m in re.findall(r"``(\w+)``", line[:38])}
    data = simulate(ANNUAL[:6]) * (1 + 0.02 * np.random.default_rng(3).standard_normal((6, 2)))
    pb = problem(ANNUAL[:6], data, rtol=1e-7)
    for kw in ({}, {"formulation": "ecfm", "sigma": 0.5}):
        res = fit(pb, TRUTH * 1.02, **kw)
        assert set(res.extra) <= keys, set(res.extra) - keys
    with pytest.raises(ValueError, match="likelihood"):
        profile_likelihood(res)


def test_force_response_matches_finite_differences_of_the_forced_solution():
    from ecfm_uq.inverse.formulations.ode_random import force_response, forced_solution

    data = simulate(ANNUAL[:7]) * (1 + 0.02 * np.random.default_rng(4).standard_normal((7, 2)))
    pb = problem(ANNUAL[:7], data, rtol=1e-11)
    e = pb.check(TRUTH * 1.02)
    ef = ExactForces(pb, forced_components(pb))
    A = force_response(pb, ef, e)
    zero = np.zeros((ef.K, ef.m))

    def readings(f):
        return forced_solution(pb, ef, e, f.reshape(ef.K, ef.m))[0][pb.mask]

    F = _fd_of(readings, zero.ravel(), rel=1e-4)
    assert np.max(np.abs(A - F)) < 1e-6 * np.max(np.abs(F))
    # the exact-match forces, put back in, reproduce the data
    out = ef.solve(e)
    got, state = forced_solution(pb, ef, e, out["forces"], out["jump"])
    np.testing.assert_allclose(got, data, rtol=1e-8)
    np.testing.assert_allclose(state(ANNUAL[1:7]), data[1:], rtol=1e-8)


def test_random_forces_tau_zero_on_exact_data_and_detected_harvest():
    times = ANNUAL[:11]
    clean = simulate(times)
    sigma = 0.03 * np.abs(clean)
    res = fit(problem(times, clean, rtol=1e-9), TRUTH * 1.02, formulation="ecfm-random",
              sigma=sigma)  # fmt: skip
    assert res.success and res.extra["tau"] == 0.0 and res.verdict.consistent
    assert type(res.extra["standard"]) is Outcome  # the standard fit: what it measured
    np.testing.assert_allclose(res.eps, TRUTH, rtol=1e-6)
    data = simulate(times, harvest=0.6)
    data = data + 0.03 * np.abs(data) * np.random.default_rng(5).standard_normal(data.shape)
    bad = fit(problem(times, data, rtol=1e-8), TRUTH * 1.02, formulation="ecfm-random",
              sigma=sigma)  # fmt: skip
    assert bad.extra["tau"] > 0 and bad.verdict.consistent is False
    assert bad.forces.values.shape == (10, 2) and np.all(bad.forces.stderr >= 0)
    with pytest.raises(ValueError, match="sigma"):
        fit(problem(times, data), TRUTH, formulation="ecfm-random")


def test_newton_starts_from_the_linear_prediction_of_the_last_solve(monkeypatch):
    """A second solve at a nearby eps starts each interval's Newton from the last forces
    moved by their derivatives: one integration per interval, the same forces as a
    solve from zero forces (to the Newton tolerance)."""
    from ecfm_uq.inverse.formulations import ode_forces

    data = simulate(ANNUAL) * (1 + 0.03 * np.random.default_rng(2).standard_normal((13, 2)))
    pb = problem(ANNUAL, data, rtol=1e-9)
    e1 = pb.check(TRUTH * 1.02)
    e2 = e1 * (1 + 1e-5 * np.arange(1, 7))  # last forces alone miss by ~1e-5 |f|
    calls = []
    real = ode_forces.solve_with_sensitivities

    def counted(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(ode_forces, "solve_with_sensitivities", counted)
    fresh = ExactForces(pb, forced_components(pb))
    cold = fresh.solve(e2)["forces"]
    n_cold = len(calls)
    warm = ExactForces(pb, forced_components(pb))
    warm.solve(e1)
    calls.clear()
    hot = warm.solve(e2)["forces"]
    assert len(calls) == warm.K and n_cold >= 2 * warm.K
    np.testing.assert_allclose(hot, cold, rtol=0, atol=1e-6 * np.max(np.abs(cold)))


def test_random_force_tau_search_meets_the_trust_region_reml_profile():
    """The random-force ECFM's likelihood ratio and tau, whose search takes its GLS
    estimates by Gauss-Newton, against the REML criterion recomputed here with
    scipy's least_squares at each tau: the same statistic, and tau its minimum."""
    import scipy.linalg
    from scipy.optimize import least_squares

    from ecfm_uq.inverse.formulations.ode_random import force_response

    times = ANNUAL[:11]
    data = simulate(times, harvest=0.3)
    sigma = 0.03 * np.abs(data)
    data = data + sigma * np.random.default_rng(8).standard_normal(data.shape)
    pb = problem(times, data, rtol=1e-9)
    res = fit(pb, TRUTH, formulation="ecfm-random", sigma=sigma)
    tau, lrt = res.extra["tau"], res.verdict.details["lrt"]
    assert tau > 0 and lrt > 1
    ef = ExactForces(pb, forced_components(pb))
    A = force_response(pb, ef, res.extra["standard"].eps)
    AWA = (A * np.repeat(1.0 / ef.dt, ef.m)) @ A.T
    Sigma = np.diag(sigma.ravel() ** 2)
    d = pb.readings

    def crit(t):
        L = np.linalg.cholesky(Sigma + t**2 * AWA)

        def white(e):
            return scipy.linalg.solve_triangular(L, pb.predict(e) - d, lower=True)

        def jac(e):
            return scipy.linalg.solve_triangular(L, pb.predict_jacobian(e), lower=True)

        e = least_squares(white, res.eps, jac=jac, xtol=1e-14, ftol=1e-14, gtol=1e-14).x
        X, r = jac(e), white(e)
        return 2 * np.sum(np.log(np.diag(L))) + np.linalg.slogdet(X.T @ X)[1] + r @ r

    c_hat = crit(tau)
    assert abs((crit(0.0) - c_hat) - lrt) < 1e-6 * lrt
    assert crit(tau * 1.1) > c_hat and crit(tau / 1.1) > c_hat


def _sin_source_problem(a=0.7, years=8):
    """y' = -a y + 0.1 sin t, y(0) = 1, read once a year (the closed form), the model
    without the source; eps = (a,)."""
    t = np.arange(1.0, years + 1.0)
    c = 0.1 / (a**2 + 1)
    data = ((1 + c) * np.exp(-a * t) + c * (a * np.sin(t) - np.cos(t)))[:, None]
    return OdeProblem(
        lambda t, y, e: -e[0] * y,
        [1.0],
        t,
        data,
        t0=0.0,
        rtol=1e-10,
        atol=1e-12,
        jac=(lambda t, y, e: -e[0] * np.eye(1), lambda t, y, e: -y.reshape(1, 1)),
    )


def test_force_basis_exact_data_give_zero_forces():
    times = np.arange(0.0, 9.0)
    pb = problem(times[1:], simulate(times)[1:], t0=0.0)
    e = pb.check(TRUTH)
    for basis in ("linear", {"rbf": 1.0}):
        out = BasisForces(pb, forced_components(pb), basis).solve(e)
        assert np.abs(out["lam"]).max() < 1e-6


def test_a_smooth_source_is_recovered_better_by_a_linear_basis():
    """The force function at the true a against the source 0.1 sin t (L2 over [0, 8];
    measured: constant 0.057, linear 0.015, of the source's 0.20)."""
    pb = _sin_source_problem()
    e = pb.check(np.array([0.7]))
    s = np.linspace(0.0, 8.0, 1601)[1:]
    err = {}
    for basis in ("constant", "linear"):
        forces = BasisForces(pb, forced_components(pb), basis)
        lam = forces.solve(e)["lam"]
        f = basis_matrix(forces.kind, forces.width, forces.knots, s) @ lam[:, 0]
        err[basis] = np.sqrt(np.mean((f - 0.1 * np.sin(s)) ** 2) * 8.0)
    assert err["linear"] < 0.4 * err["constant"]
    # the constant basis is the interval-by-interval ECFM's (no datum at t0: no jump)
    ref = ExactForces(pb, forced_components(pb)).solve(e)["forces"]
    lam = BasisForces(pb, forced_components(pb), "constant").solve(e)["lam"]
    np.testing.assert_allclose(lam, ref, atol=1e-8)


@pytest.mark.parametrize("basis", ["linear", {"rbf": 1.0}])
def test_force_basis_gradient_against_finite_differences_and_fit(basis):
    pb = _sin_source_problem()
    e = pb.check(np.array([0.5]))
    forces = BasisForces(pb, forced_components(pb), basis)
    out = forces.solve(e)
    g = out["J"].T @ out["r"]  # the objective's gradient (exact: the envelope derivative)
    fd = _fd_of(lambda x: np.atleast_1d(0.5 * np.sum(forces.solve(x)["r"] ** 2)), e, 1e-5)
    np.testing.assert_allclose(g, fd[0], rtol=1e-5)
    res = fit(pb, [0.5], formulation="ecfm", options={"force_basis": basis})
    assert res.success and res.forces.values.shape == (8, 1)
    assert not res.uncertainty.success and "force_basis" in res.uncertainty.message


def test_force_basis_option_by_name():
    """ "constant" is the default (the same fit); a datum at t0 and unknown names are
    refused by name."""
    data = simulate(ANNUAL)
    pb = problem(ANNUAL, data)
    res = fit(pb, TRUTH * 1.05, formulation="ecfm", options={"force_basis": "constant"})
    np.testing.assert_allclose(res.eps, fit(pb, TRUTH * 1.05, formulation="ecfm").eps)
    with pytest.raises(ValueError, match=r"options\['force_basis'\].*datum at t0"):
        fit(pb, TRUTH * 1.05, formulation="ecfm", options={"force_basis": "linear"})
    with pytest.raises(ValueError, match="`force_basis` must be"):
        fit(pb, TRUTH * 1.05, formulation="ecfm", options={"force_basis": "cubic"})
