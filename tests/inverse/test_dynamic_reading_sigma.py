"""A sigma per reading ``(n_steps, C)`` for a :class:`DynamicInverseProblem` (noise that
changes with time), against independent computations: the same readings fitted as a
:class:`ModelProblem` with one sigma per observation (``sigma.ravel()``), scipy's
``curve_fit(sigma=..., absolute_sigma=True)``, central differences of the weighted
objective (forward and adjoint gradients), the per-sensor ``(C,)`` path for a sigma
constant in time, the ECFM without sigma (its estimate does not depend on it); refusals
by their message, before any march."""

import numpy as np
import pytest
from _models import diffusion, logistic
from scipy import optimize

from ecfm_uq.inverse import DynamicInverseProblem, ModelProblem, fit, profile_intervals
from ecfm_uq.inverse.core.finite_differences import fd_gradient
from ecfm_uq.inverse.problems.whitening import dynamic_noise_model, whitened_problem
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import march

EPS0 = [1.5, 0.5]


@pytest.fixture(scope="module")
def burgers():
    """Burgers, 4 sensors, 20 readings each; the noise grows in time (1 % to 10 % of the
    readings' scale) and differs between sensors."""
    m = BurgersModel(n_modes=12, n_steps=20, T=1.0, newton_tol=1e-12)
    V0 = m.true_data([1.75, 1.0])
    P, C = m.n_steps, V0.shape[1]
    scale = np.abs(V0[1:]).max()
    growth = np.linspace(0.01, 0.10, P)[:, None]  # 1 % early, 10 % late
    sig = scale * growth * np.array([1.0, 1.5, 0.8, 1.2])
    V = V0.copy()
    V[1:] += sig * np.random.default_rng(11).standard_normal((P, C))
    return m, V, sig


def _dynamic(m, V, **kw):
    return DynamicInverseProblem(
        m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V, solve_tol=1e-12, **kw
    )


def _readings(p):
    def model(eps):
        return p.predictions(p.solve(eps))[1:]

    return model


@pytest.fixture(scope="module")
def fitted(burgers):
    m, V, sig = burgers
    p = _dynamic(m, V)
    res = fit(p, EPS0, sigma=sig)
    mp = fit(ModelProblem(_readings(_dynamic(m, V)), V[1:], jac="3-point"), EPS0,
             sigma=sig.ravel())  # fmt: skip
    return p, res, mp


def test_per_reading_sigma_equals_a_model_problem_of_the_readings(burgers, fitted):
    m, V, sig = burgers
    p, res, mp = fitted
    assert res.success and mp.success, res.message
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-4)
    assert res.uncertainty.noise_model == "known" and res.uncertainty.dof is None
    assert res.verdict.test == "chi2"
    assert res.verdict.details["dof"] == sig.size - 2
    assert res.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    e = (V[1:] - _readings(p)(res.eps)) / sig  # chi2 by hand, in the data's units
    assert res.verdict.details["chi2"] == pytest.approx(np.sum(e * e), rel=1e-9)
    assert res.verdict.p_value == pytest.approx(mp.verdict.p_value, rel=1e-5)
    # d eps / dv in the data's units (readings time by time), as the ModelProblem's
    assert res.uncertainty.jacobian.shape == (2, sig.size)
    np.testing.assert_allclose(res.uncertainty.jacobian, mp.uncertainty.jacobian, rtol=1e-5,
                               atol=1e-8 * np.abs(mp.uncertainty.jacobian).max())  # fmt: skip
    # the delta method with the readings' variances
    D = res.uncertainty.jacobian
    np.testing.assert_allclose(res.uncertainty.cov, D @ np.diag(sig.ravel() ** 2) @ D.T,
                               rtol=1e-8)  # fmt: skip
    assert "sigma per reading" in res.likelihood.description


def test_per_reading_profile_intervals_equal_the_model_problems(fitted):
    _, res, mp = fitted
    np.testing.assert_allclose(profile_intervals(res), profile_intervals(mp), rtol=1e-6)


def test_per_reading_sigma_equals_curve_fit_absolute_sigma(burgers, fitted):
    m, V, sig = burgers
    p, res, _ = fitted
    model = _readings(_dynamic(m, V))
    popt, pcov = optimize.curve_fit(
        lambda x, a, b: model(np.array([a, b])).ravel(), None, V[1:].ravel(), p0=EPS0,
        sigma=sig.ravel(), absolute_sigma=True, epsfcn=1e-12,
    )  # fmt: skip
    np.testing.assert_allclose(res.eps, popt, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, np.sqrt(np.diag(pcov)), rtol=1e-4)


@pytest.mark.parametrize("gradient", ["forward", "adjoint"])
def test_the_weighted_objective_gradient_and_residual_jacobian_are_exact(burgers, gradient):
    """The whitened copy's objective: z = dt/2 sum ((M theta_i - v_i)/sigma_i)^2 by hand,
    its gradient (forward sensitivities or the adjoint's load) against central
    differences, and the residual's Jacobian against differences of the residual."""
    m, V, sig = burgers
    p = _dynamic(m, V, gradient=gradient)
    w = whitened_problem(p, dynamic_noise_model(sig, m.n_steps, 4))
    x = np.array([1.6, 0.8])
    z, g = w.objective("standard")(x)
    e = (_readings(p)(x) - V[1:]) / sig
    assert z == pytest.approx(0.5 * m.dt * np.sum(e * e), rel=1e-12)
    fd = fd_gradient(lambda y: w.loss(y, "standard"), x, 1e-5)
    np.testing.assert_allclose(g, fd, rtol=1e-7)
    r, J, _ = w.residual(x)
    np.testing.assert_allclose(r, np.sqrt(m.dt) * e.ravel(), rtol=1e-12)
    Jfd = np.column_stack(
        [(w.residual(x + h)[0] - w.residual(x - h)[0]) / 2e-6 for h in 1e-6 * np.eye(2)]
    )
    np.testing.assert_allclose(J, Jfd, rtol=1e-5, atol=1e-8 * np.abs(J).max())
    # every optimizer path reaches the same estimate
    ref = fit(p, EPS0, sigma=sig)
    bfgs = fit(_dynamic(m, V, gradient=gradient), EPS0, sigma=sig, method="BFGS")
    assert bfgs.success, bfgs.message
    np.testing.assert_allclose(bfgs.eps, ref.eps, rtol=1e-7)


def test_a_sigma_constant_in_time_is_the_per_sensor_sigma(burgers):
    """np.tile(s, (n_steps, 1)) is the (C,) sigma s: the whitened problems' residual,
    Jacobian and adjoint gradient agree to round-off at any eps, and the fits to what a
    fit reproduces (cold Newton starts: the estimate of one sigma from two starting
    points differs by ~2e-10 relative, the floor of the least-squares stop)."""
    m, V, _ = burgers
    s = np.array([0.01, 0.02, 0.03, 0.05])
    tiled = np.tile(s, (m.n_steps, 1))
    x = np.array([1.6, 0.8])
    copies = [
        whitened_problem(
            _dynamic(m, V, gradient="adjoint"), dynamic_noise_model(sigma, m.n_steps, 4)
        )  # fmt: skip
        for sigma in (s, tiled, tiled.ravel())
    ]
    assert [w.reading_sigma is None for w in copies] == [True, False, False]
    for formulation in ("standard", "ecfm"):
        r1, J1, _ = copies[0].residual(x, formulation)
        g1 = copies[0].objective(formulation)(x)[1]
        for w in copies[1:]:
            r, J, _ = w.residual(x, formulation)
            np.testing.assert_allclose(r, r1, rtol=1e-12, atol=1e-13 * np.abs(r1).max())
            np.testing.assert_allclose(J, J1, rtol=1e-12, atol=1e-13 * np.abs(J1).max())
            np.testing.assert_allclose(w.objective(formulation)(x)[1], g1, rtol=1e-11)
    for formulation in ("standard", "ecfm"):
        kw = dict(formulation=formulation)
        one = fit(_dynamic(m, V, warm_start=False), EPS0, sigma=s, **kw)
        per = fit(_dynamic(m, V, warm_start=False), EPS0, sigma=tiled, **kw)
        flat = fit(_dynamic(m, V, warm_start=False), EPS0, sigma=tiled.ravel(), **kw)
        assert one.success and per.success, per.message
        for other in (per, flat):
            # the same least-squares problem run three times: each run's status certifies
            # its estimate within c sqrt(p) standard errors x sqrt(chi2 / dof) of the
            # optimum (c its relative offset, as below), so two runs agree to the sum;
            # which point inside it a run stops at is the BLAS kernel's and scipy's last
            # bits (2.3e-9 relative apart with the minimum versions, ~1e-10 with current)
            chi2, dof = one.verdict.details["chi2"], one.verdict.details["dof"]
            certified = (one.optimality + other.optimality) * np.sqrt(one.eps.size)
            certified *= one.uncertainty.stderr * np.sqrt(max(chi2 / dof, 1.0))
            assert np.all(np.abs(other.eps - one.eps) <= certified), (other.eps, certified)
            np.testing.assert_allclose(other.uncertainty.cov, one.uncertainty.cov, rtol=1e-7)
            D = one.uncertainty.jacobian  # the ECFM's: differenced in the data
            np.testing.assert_allclose(other.uncertainty.jacobian, D, rtol=1e-7,
                                       atol=1e-7 * np.abs(D).max())  # fmt: skip
            assert other.verdict.details["chi2"] == pytest.approx(
                one.verdict.details["chi2"], rel=1e-9
            )
        if formulation == "standard":
            np.testing.assert_allclose(profile_intervals(per), profile_intervals(one),
                                       rtol=1e-8)  # fmt: skip


def test_the_exact_match_ecfm_estimate_ignores_a_per_reading_sigma(burgers):
    """W_i M theta_i = W_i v_i has the solutions of M theta_i = v_i: the estimate and the
    forces are those without sigma; sigma sets the covariance (delta method) and the chi2
    verdict on the whitened unforced residual."""
    m, V, sig = burgers
    res = fit(_dynamic(m, V), EPS0, formulation="ecfm", sigma=sig)
    plain = fit(_dynamic(m, V), EPS0, formulation="ecfm")
    assert res.success and plain.success, res.message
    # two optimizer runs of one objective: equal to the precision the status test certifies
    # (a Gauss-Newton step below 1e-6 sqrt(p) standard errors; measured 0 with the current
    # scipy, 4e-8 standard errors with the minimum versions); were sigma to move the ECFM
    # estimate, it would move it by a fraction of a standard error
    np.testing.assert_allclose(res.eps, plain.eps, rtol=0, atol=1e-6 * res.uncertainty.stderr.min())
    # at one eps the forces (no optimizer involved) are those of the problem without sigma
    forces = _dynamic(m, V).solve(res.eps, "ecfm").lam
    np.testing.assert_allclose(res.forces, forces, rtol=1e-8, atol=1e-10 * np.abs(forces).max())
    D = res.uncertainty.jacobian
    np.testing.assert_allclose(res.uncertainty.cov, D @ np.diag(sig.ravel() ** 2) @ D.T,
                               rtol=1e-8)  # fmt: skip
    e = (V[1:] - _readings(_dynamic(m, V))(res.eps)) / sig
    assert res.verdict.test == "chi2"
    assert res.verdict.details["chi2"] == pytest.approx(np.sum(e * e), rel=1e-6)


# -- a model not designed for it: a P = 3 random diffusion transient -------------------


def test_heteroscedastic_random_diffusion_weighted_fit_differs_and_equals_model_problem():
    """-(10^eps0 + 0.3 sin(pi x)(w - 1/2)) u'' = eps1 from rest, P = 3 (a germ, order 2),
    3 sensors, sparse; the noise grows from 1 % to 10 % of the readings in time."""
    system, M_obs = diffusion(N=12, dim=1, order=2, n_forces=3)
    assert system.P == 3
    truth = np.array([-1.0, 2.0])
    n_steps, dt = 12, 0.02
    Theta0 = np.zeros(system.shape)
    clean = march(system, truth, Theta0, dt=dt, n_steps=n_steps, tol=1e-13)
    V0 = clean.Theta @ system.E1 @ M_obs.T
    growth = np.linspace(0.01, 0.10, n_steps)[:, None]
    sig = growth * np.abs(V0[1:]).max() * np.ones((1, 3))
    rng = np.random.default_rng(5)
    V = V0.copy()
    V[1:] += sig * rng.standard_normal(sig.shape)

    def problem():
        return DynamicInverseProblem(system, Theta0, dt, n_steps, M_obs, V, solve_tol=1e-13)

    # the weighted objective's adjoint gradient (P = 3, sparse) against central differences
    w = whitened_problem(problem(), dynamic_noise_model(sig, n_steps, 3))
    assert w.gradient == "adjoint"
    x = np.array([-0.9, 1.8])
    np.testing.assert_allclose(
        w.objective("standard")(x)[1],
        fd_gradient(lambda y: w.loss(y, "standard"), x, 1e-5),
        rtol=1e-7,
    )
    start = [-0.8, 1.5]
    res = fit(problem(), start, sigma=sig)
    flat = fit(problem(), start, sigma=float(sig.mean()))  # the same noise at every reading
    p = problem()
    mp = fit(ModelProblem(_readings(p), V[1:], jac="3-point"), start, sigma=sig.ravel())
    assert res.success and flat.success and mp.success, res.message
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-4)
    assert res.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    # weighting matters here: the estimates differ by a sizeable part of a standard error
    gap = np.abs(res.eps - flat.eps) / res.uncertainty.stderr
    assert gap.max() > 0.3, gap  # measured 0.61
    assert np.abs(res.eps - flat.eps).max() > 1e3 * np.abs(res.eps - mp.eps).max()


def test_adaptive_scheme_logistic_growth_per_reading_sigma_equals_model_problem():
    """The logistic growth u' = a u (1 - u/K) on the frozen error-controlled grid of
    scheme='adaptive' (steps between the data times), one sensor, noise 1 % to 10 %."""

    system = logistic()
    T, n = 6.0, 8
    t = np.linspace(0.0, T, n + 1)
    V0 = (2.0 / (1 + (2.0 / 0.1 - 1) * np.exp(-1.5 * t)))[:, None]  # a = 1.5, K = 2
    sig = np.linspace(0.01, 0.10, n)[:, None] * V0[1:]
    V = V0.copy()
    V[1:] += sig * np.random.default_rng(2).standard_normal(sig.shape)
    p = DynamicInverseProblem(system, [0.1], T / n, n, np.eye(1), V, scheme="adaptive",
                              rtol=1e-4)  # fmt: skip
    start = [1.2, 2.5]
    p.freeze_steps([1.5, 2.0])  # near the estimate: the check there keeps this grid
    res = fit(p, start, sigma=sig)
    assert res.success, res.message
    assert p.steps.n_steps > n  # steps between the data times
    assert res.extra["steps"]["met"] and not res.extra["steps"]["refrozen"]
    mp = fit(ModelProblem(_readings(p), V[1:], jac="3-point"), start, sigma=sig.ravel())
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    np.testing.assert_allclose(res.uncertainty.stderr, mp.uncertainty.stderr, rtol=1e-4)
    assert res.verdict.details["chi2"] == pytest.approx(mp.verdict.details["chi2"], rel=1e-6)
    flat = fit(p, start, sigma=float(sig.mean()))
    assert np.abs(res.eps - flat.eps).max() > 1e3 * np.abs(res.eps - mp.eps).max()


# -- refusals, before any march ----------------------------------------------------------


def test_a_malformed_sigma_is_refused_by_name_before_any_march(burgers):
    m, V, _ = burgers
    P, C = m.n_steps, 4
    dyn = _dynamic(m, V)
    marched = []
    dyn.solve = lambda *a, **k: marched.append(1)  # any march would be counted
    shapes = r"`sigma` of a time series of 20 readings of 4 sensors.*\(4,\).*\(4, 4\).*\(20, 4\)"
    for bad in (
        np.full(3, 0.01),
        np.full((P, C + 1), 0.01),
        np.full((P - 1, C), 0.01),
        np.full((P, C, 1), 0.01),
        np.full((C, P), 0.01),
    ):
        with pytest.raises(ValueError, match=shapes + ".*got shape"):
            fit(dyn, EPS0, sigma=bad)
    with pytest.raises(ValueError, match=r"initial row.*pass sigma\[1:\]"):
        fit(dyn, EPS0, sigma=np.full((P + 1, C), 0.01))
    bad = np.full((P, C), 0.01)
    bad[3, 2] = 0.0
    with pytest.raises(ValueError, match=r"`sigma`.*reading \(3, 2\) \(V\[4, 2\]\) is 0"):
        fit(dyn, EPS0, sigma=bad)
    bad[3, 2] = np.nan
    with pytest.raises(ValueError, match=r"reading \(3, 2\).*is nan"):
        fit(dyn, EPS0, sigma=bad)
    with pytest.raises(TypeError, match="`sigma` of a time series"):
        fit(dyn, EPS0, sigma=[[0.1, "a"]])
    for formulation in ("standard", "ecfm"):  # the per-sensor messages are kept
        with pytest.raises(ValueError, match=r"not positive definite"):
            fit(dyn, EPS0, formulation=formulation, sigma=np.ones((C, C)))
    assert marched == []


def test_a_square_sigma_is_the_covariance_also_when_n_steps_equals_c():
    """n_steps == C: (C, C) is the sensors' covariance; a sigma per reading goes flattened."""
    m = BurgersModel(n_modes=8, n_steps=4, T=0.3, newton_tol=1e-12)
    V = m.true_data([1.75, 1.0])
    V[1:] += 0.01 * np.random.default_rng(0).standard_normal(V[1:].shape)
    dyn = _dynamic(m, V)
    per_reading = np.array([[0.01, 0.02, 0.03, 0.04]] * 4) * np.array([[1], [2], [4], [8]])
    with pytest.raises(ValueError, match=r"not symmetric.*also when n_steps == C.*\(16,\)"):
        fit(dyn, EPS0, sigma=per_reading)
    res = fit(dyn, EPS0, sigma=per_reading.ravel())
    mp = fit(ModelProblem(_readings(_dynamic(m, V)), V[1:], jac="3-point"), EPS0,
             sigma=per_reading.ravel())  # fmt: skip
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, mp.eps, rtol=1e-6)
    cov = np.diag([1e-4, 2e-4, 3e-4, 4e-4])
    as_cov = fit(_dynamic(m, V), EPS0, sigma=cov)
    per_sensor = fit(_dynamic(m, V), EPS0, sigma=np.sqrt(np.diag(cov)))
    # two whitenings of one sigma: the same least-squares problem, run twice. Each run's
    # status certifies its estimate within c sqrt(p) standard errors x sqrt(chi2 / dof) of
    # the optimum (c its relative offset: the Gauss-Newton step bounded by Cauchy-Schwarz,
    # convergence.py), so they agree to the sum of the two; which point inside it each run
    # stops at depends on the BLAS kernel's last bits (3e-8 apart under Prescott's, 5e-9
    # under SkylakeX's), so nothing tighter is machine-independent
    assert as_cov.success and per_sensor.success
    n_eps, chi2 = 2, as_cov.verdict.details["chi2"]
    certified = (as_cov.optimality + per_sensor.optimality) * np.sqrt(n_eps)
    certified *= as_cov.uncertainty.stderr * np.sqrt(chi2 / as_cov.verdict.details["dof"])
    assert np.all(np.abs(as_cov.eps - per_sensor.eps) <= certified), (as_cov.eps, certified)
    np.testing.assert_allclose(as_cov.uncertainty.cov, per_sensor.uncertainty.cov, rtol=1e-6)
    assert as_cov.uncertainty.jacobian.shape == (2, 16)


def test_uncertainty_called_directly_takes_the_same_sigma_as_fit(burgers, fitted):
    """``DynamicInverseProblem.uncertainty(eps, sigma=array)`` whitens as ``fit`` does:
    a per-reading sigma and a per-sensor one give the fit's covariance and its d eps/dv."""
    m, V, sig = burgers
    p, res, _ = fitted
    direct = p.uncertainty(res.eps, "standard", sigma=sig, covariance="gauss-newton")
    np.testing.assert_allclose(direct.cov, res.uncertainty.cov, rtol=1e-8)
    np.testing.assert_allclose(direct.jacobian, res.uncertainty.jacobian, rtol=1e-8,
                               atol=1e-12 * np.abs(res.uncertainty.jacobian).max())  # fmt: skip
    s_c = sig.mean(axis=0)  # one per sensor, the same at every time
    per_sensor = fit(_dynamic(m, V), EPS0, sigma=s_c)
    direct = p.uncertainty(per_sensor.eps, "standard", sigma=s_c, covariance="gauss-newton")
    np.testing.assert_allclose(direct.cov, per_sensor.uncertainty.cov, rtol=1e-8)
    with pytest.raises(ValueError, match="sigma"):
        p.uncertainty(res.eps, "standard", sigma=np.ones((3, 3, 3)))
