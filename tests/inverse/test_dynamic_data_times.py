"""DynamicInverseProblem with data at their own times (``t``): readings at some steps, the
standard fit on those, the ECFM with one force per data interval; against closed forms of
the backward-Euler decay, central differences, and the every-step problem."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.inverse import fit
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, NonlinearTerm, march

RATES = np.array([1.0, 2.5])  # theta_i' = -a k_i theta_i
THETA0 = np.array([1.0, -0.7])
A_TRUE = 0.8
DT, N_STEPS, EVERY = 0.05, 24, 4


def _system():
    terms = [LinearTerm(np.diag(RATES), Coefficient.parameter(0))]
    return GalerkinSystem(terms, n_eps=1, Gamma=np.eye(2), M=np.eye(2), name="decay")


def _be_states(a, source=None):
    """Backward Euler of theta' = -a k theta + f(t) by hand: (n_steps + 1, 2).
    ``source(s)`` is the constant source on step s -> s + 1."""
    th = np.zeros((N_STEPS + 1, 2))
    th[0] = THETA0
    for s in range(N_STEPS):
        f = np.zeros(2) if source is None else source(s)
        th[s + 1] = (th[s] + DT * f) / (1.0 + a * RATES * DT)
    return th


def _problem(V, steps, **kw):
    return DynamicInverseProblem(
        _system(), THETA0, DT, N_STEPS, np.eye(2), V, t=DT * steps, solve_tol=1e-13, **kw
    )


STEPS = np.arange(EVERY, N_STEPS + 1, EVERY)  # data every 4th step, not at t0


def test_backward_euler_closed_form_is_the_march():
    """The hand recursion is theta0 (1 + a k dt)^-s (the test's truth is independent)."""
    th = _be_states(A_TRUE)
    s = np.arange(N_STEPS + 1)[:, None]
    np.testing.assert_allclose(th, THETA0 * (1 + A_TRUE * RATES * DT) ** (-s), rtol=1e-14)


def test_standard_objective_by_definition_and_gradients():
    """z = w/2 sum_j |M theta(t_j) - v_j|^2 over the data times only, w the mean data
    spacing; forward and adjoint gradients against central differences."""
    V = _be_states(A_TRUE)[STEPS] + 0.01 * np.cos(np.arange(STEPS.size))[:, None]
    prob = _problem(V, STEPS)
    a = 0.6
    z, g, _ = prob.standard_objective(np.array([a]))
    e = _be_states(a)[STEPS] - V
    assert z == pytest.approx(0.5 * EVERY * DT * np.sum(e**2), rel=1e-11)
    h = 1e-6
    fd = (prob.loss([a + h], "standard") - prob.loss([a - h], "standard")) / (2 * h)
    assert g[0] == pytest.approx(fd, rel=1e-7)
    adj = _problem(V, STEPS, gradient="adjoint")
    assert adj.standard_objective(np.array([a]))[1][0] == pytest.approx(g[0], rel=1e-10)
    r, J, _ = prob.residual(np.array([a]), "standard")
    assert r.shape == (STEPS.size * 2,) and 0.5 * r @ r == pytest.approx(z, rel=1e-12)
    assert (J.T @ r)[0] == pytest.approx(g[0], rel=1e-10)


def test_standard_fit_recovers_the_rate_from_sparse_data():
    V = _be_states(A_TRUE)[STEPS]
    res = fit(_problem(V, STEPS), [0.3], formulation="standard")
    assert res.success
    assert res.eps[0] == pytest.approx(A_TRUE, rel=1e-8)


def test_ecfm_with_exact_data_has_zero_forces_and_finds_the_rate():
    prob = _problem(_be_states(A_TRUE)[STEPS], STEPS)
    z, g, traj = prob.ecfm_objective(np.array([A_TRUE]))
    assert np.max(np.abs(traj.lam)) < 1e-9 and z < 1e-18 and abs(g[0]) < 1e-9
    # away from the truth the forces are not zero, and the data are met exactly
    _, _, traj = prob.ecfm_objective(np.array([0.5]), gradient=False)
    assert np.max(np.abs(traj.lam)) > 1e-2
    reads = traj.Theta[STEPS, :, 0]
    np.testing.assert_allclose(reads, prob.V[1:], atol=1e-11)
    res = fit(prob, [0.3], formulation="ecfm")
    assert res.success
    assert res.eps[0] == pytest.approx(A_TRUE, rel=1e-8)


def test_a_missing_source_shows_up_as_the_force_of_its_interval():
    """Data with a source f on the 3rd data interval only (steps 8..12): at the true rate the
    exact-match forces are f there and zero in every other interval (a held force is
    exactly the missing constant source), and held over that interval's steps."""
    f = np.array([0.9, -0.4])
    V = _be_states(A_TRUE, lambda s: f if 8 <= s < 12 else np.zeros(2))[STEPS]
    prob = _problem(V, STEPS)
    _, _, traj = prob.ecfm_objective(np.array([A_TRUE]), gradient=False)
    lam = traj.lam[STEPS]  # the force of each interval (held up to its data time)
    want = np.zeros_like(lam)
    want[2] = f
    np.testing.assert_allclose(lam, want, atol=1e-10)
    np.testing.assert_allclose(traj.lam[9:13], np.tile(f, (4, 1)), atol=1e-10)
    assert np.all(traj.lam[0] == 0)


@pytest.mark.parametrize(
    "steps, scheme",
    [(STEPS, "euler"), (np.array([0, 3, 4, 9, 17, 24]), "euler"), (STEPS, "bdf2")],
)
def test_ecfm_objective_and_gradient_against_central_differences(steps, scheme):
    """z = 1/2 sum_j dt_j |lam_j|^2 (uneven intervals too, a reading at t0 not fitted;
    BDF2 marches across the data times)."""
    f = np.array([0.5, 0.3])
    V = _be_states(A_TRUE, lambda s: f if s >= 10 else np.zeros(2))[steps]
    prob = _problem(V, steps, scheme=scheme)
    x = np.array([0.55])
    z, g, traj = prob.ecfm_objective(x)
    fitted = steps[steps > 0]
    widths = DT * np.diff(np.r_[0, fitted])
    lam = traj.lam[fitted]
    assert z == pytest.approx(0.5 * np.sum(widths[:, None] * lam**2), rel=1e-13)
    h = 1e-6
    fd = (prob.loss(x + h, "ecfm") - prob.loss(x - h, "ecfm")) / (2 * h)
    assert g[0] == pytest.approx(fd, rel=1e-6)
    r, J, _ = prob.residual(x, "ecfm")
    assert 0.5 * r @ r == pytest.approx(z, rel=1e-12)
    assert (J.T @ r)[0] == pytest.approx(g[0], rel=1e-10)


def test_every_step_is_the_default_problem_bit_for_bit():
    V = _be_states(0.7) + 0.01
    dense = DynamicInverseProblem(_system(), THETA0, DT, N_STEPS, np.eye(2), V)
    every = DynamicInverseProblem(
        _system(), THETA0, DT, N_STEPS, np.eye(2), V, t=DT * np.arange(N_STEPS + 1)
    )
    assert not every.sparse
    for f in ("standard", "ecfm"):
        z0, g0, t0 = getattr(dense, f"{f}_objective")(np.array([0.5]))
        z1, g1, t1 = getattr(every, f"{f}_objective")(np.array([0.5]))
        assert z0 == z1 and np.array_equal(g0, g1) and np.array_equal(t0.lam, t1.lam)


def _at_steps(model, steps):
    """The model's true data at the given steps (read at their times) and its problem."""
    V = model.true_data(np.array([1.75, 1.0]))[steps]
    prob = DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V,
        t=model.dt * steps, solve_tol=1e-12,
    )  # fmt: skip
    return prob, V


def test_burgers_with_data_every_fifth_step():
    model = BurgersModel(n_modes=12, n_steps=20, T=1.0, newton_tol=1e-12)
    steps = np.arange(5, 21, 5)
    prob, V = _at_steps(model, steps)
    x = np.array([1.6, 0.8])
    z, g, traj = prob.ecfm_objective(x)
    assert np.all(np.isfinite(traj.lam)) and np.all(np.isfinite(g)) and z > 0
    np.testing.assert_allclose(traj.Theta[steps, :, 0] @ model.M_obs.T, V, atol=1e-9)
    h = 1e-5
    fd = [
        (prob.loss(x + h * e, "ecfm") - prob.loss(x - h * e, "ecfm")) / (2 * h) for e in np.eye(2)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    z_true, _, traj = prob.ecfm_objective(np.array([1.75, 1.0]), gradient=False)
    assert z_true < 1e-16


@pytest.mark.parametrize(
    "t, match",
    [
        (DT * np.array([4, 8.5, 12]), "on the step grid"),
        (DT * np.array([8, 4, 12]), "strictly increasing"),
        (DT * np.array([4, 8, 8]), "repeated"),
        (DT * np.array([4, 8, N_STEPS + 4]), "lie in the march"),
        (DT * np.array([-1, 4, 8]), "lie in the march"),
        (np.array([]), "empty"),
        (np.array([0.0]), "no data time after t0"),
    ],
)
def test_bad_data_times_are_refused_naming_t(t, match):
    V = np.zeros((len(t), 2))
    with pytest.raises(ValueError, match=match) as err:
        _problem(V, np.asarray(t) / DT)
    assert "`t`" in str(err.value)


def test_data_of_another_length_than_t_is_refused():
    with pytest.raises(ValueError, match="V"):
        _problem(np.zeros((3, 2)), STEPS)


def test_compiled_and_generic_marches_give_the_same_forces():
    """The forces enter as a load tabulated per march (compiled kernel) or evaluated per
    step (generic path): the same objective, gradient and forces."""
    f = np.array([0.5, 0.3])
    V = _be_states(A_TRUE, lambda s: f if s >= 10 else np.zeros(2))[STEPS]
    x = np.array([0.55])
    fast = _problem(V, STEPS)
    slow = _problem(V, STEPS, solver={"compiled": False})
    z0, g0, t0 = fast.ecfm_objective(x)
    z1, g1, t1 = slow.ecfm_objective(x)
    assert t0.plan.path == "compiled-p1" and t1.plan.path == "generic"
    assert z1 == pytest.approx(z0, rel=1e-10) and g1[0] == pytest.approx(g0[0], rel=1e-9)
    np.testing.assert_allclose(t1.lam, t0.lam, rtol=1e-9, atol=1e-12)


def test_stochastic_system_forces_act_on_the_mean():
    """P > 1 (random viscosity, data every 2nd step): the match holds on the mean state,
    the forces are zero at the truth, and the gradient equals central differences."""
    model = BurgersModel(
        n_modes=8, n_steps=10, T=0.5, viscosity_chaos=ChaosBasis(2), viscosity_spread=0.4
    )
    steps = np.arange(2, 11, 2)
    prob, V = _at_steps(model, steps)
    x = np.array([1.6, 0.8])
    z, g, traj = prob.ecfm_objective(x)
    mean = traj.Theta[steps] @ model.system.E1
    np.testing.assert_allclose(mean @ model.M_obs.T, V, atol=1e-9)
    h = 1e-5
    fd = [
        (prob.loss(x + h * e, "ecfm") - prob.loss(x - h * e, "ecfm")) / (2 * h) for e in np.eye(2)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    assert prob.loss(np.array([1.75, 1.0]), "ecfm") < 1e-16


def _be_rate_derivative(a, steps):
    """d theta_s / d a of theta0 (1 + a k dt)^-s, by hand: (n_t, 2)."""
    s = np.asarray(steps)[:, None]
    return -s * RATES * DT * THETA0 * (1 + a * RATES * DT) ** (-s - 1.0)


def test_standard_fit_uncertainty_matches_the_closed_form_gauss_newton():
    """Noisy readings at the data times only, sigma known: stderr = sigma / |J|, J the
    closed-form derivative of the fitted readings (independent of the weight w); a sigma
    per reading ((n_t, C), the readings fitted) whitens reading by reading."""
    rng = np.random.default_rng(7)
    sigma = 0.02
    V = _be_states(A_TRUE)[STEPS] + sigma * rng.standard_normal((STEPS.size, 2))
    res = fit(_problem(V, STEPS), [0.3], sigma=sigma)
    assert res.success and res.uncertainty.success
    Jc = _be_rate_derivative(res.eps[0], STEPS).ravel()
    assert res.uncertainty.stderr[0] == pytest.approx(sigma / np.linalg.norm(Jc), rel=1e-6)
    S = np.tile([sigma, 3 * sigma], (STEPS.size, 1))
    S[::2] *= 2.0
    res = fit(_problem(V, STEPS), [0.3], sigma=S)
    assert res.success and res.uncertainty.success
    Jc = (_be_rate_derivative(res.eps[0], STEPS) / S).ravel()
    assert res.uncertainty.stderr[0] == pytest.approx(1.0 / np.linalg.norm(Jc), rel=1e-6)
    # the estimate is the weighted least-squares root: sum J_w r_w = 0 at it
    r = ((_be_states(res.eps[0])[STEPS] - V) / S).ravel()
    assert abs(Jc @ r) < 1e-8 * np.linalg.norm(Jc) * np.linalg.norm(r)


def test_adaptive_steps_between_sparse_data_times_recover_the_exact_rate():
    """Readings of the exact solution theta0 exp(-a k t) at 5 uneven times: backward
    Euler on the data's spacing is biased, the adaptive grid between them is not."""
    t = np.array([0.25, 0.5, 1.0, 1.5, 2.0])
    V = THETA0 * np.exp(-A_TRUE * RATES * t[:, None])
    coarse = DynamicInverseProblem(_system(), THETA0, 0.25, 8, np.eye(2), V, t=t)
    adaptive = DynamicInverseProblem(
        _system(), THETA0, 0.25, 8, np.eye(2), V, t=t, scheme="adaptive", rtol=1e-6
    )
    assert abs(fit(coarse, [0.3]).eps[0] - A_TRUE) > 0.05
    res = fit(adaptive, [0.3])
    assert res.success and res.extra["steps"]["met"]
    assert res.eps[0] == pytest.approx(A_TRUE, rel=2e-4)
    # the ECFM on the frozen grid (refused before the adaptive ECFM existed): exact data
    # of the ODE, so the forces at the estimate are of the grid's rtol only
    z, _, traj = adaptive.ecfm_objective(res.eps)
    assert z < 1e-8 and np.abs(traj.lam).max() < 1e-3


def test_ecfm_fit_with_noisy_sparse_data_reports_interval_forces():
    rng = np.random.default_rng(3)
    V = _be_states(A_TRUE)[STEPS] + 0.01 * rng.standard_normal((STEPS.size, 2))
    res = fit(_problem(V, STEPS), [0.3], formulation="ecfm", sigma=0.01)
    assert res.success and res.uncertainty.success
    assert res.forces.shape == (N_STEPS + 1, 2) and np.all(res.forces[0] == 0)
    # held over each interval: constant on the steps of one interval
    for a, b in zip(np.r_[0, STEPS[:-1]], STEPS, strict=True):
        assert np.all(res.forces[a + 1 : b + 1] == res.forces[b])
    assert abs(res.eps[0] - A_TRUE) < 5 * res.uncertainty.stderr[0]


def test_ecfm_uncertainty_data_derivative_against_refits():
    """The sparse ECFM's d eps_hat / dV (Gauss-Newton, the forces' exact data derivative):
    at exact data (zero forces) it is the derivative of the estimate itself, measured by
    refitting with each reading moved by +-h."""
    V = _be_states(A_TRUE)[STEPS]
    prob = _problem(V, STEPS)
    res = fit(prob, [0.3], formulation="ecfm", sigma=0.01, tol=1e-14)
    D = res.uncertainty.jacobian  # (1, n_data)
    assert D.shape == (1, STEPS.size * 2)
    h = 1e-5
    fd = np.zeros(D.shape[1])
    for i in range(fd.size):
        moved = []
        for sgn in (1, -1):
            W = prob.V.copy()
            W[1:].reshape(-1)[i] += sgn * h
            moved.append(fit(prob.with_data(W), [A_TRUE], formulation="ecfm", tol=1e-14,
                             uncertainty=False).eps[0])  # fmt: skip
        fd[i] = (moved[0] - moved[1]) / (2 * h)
    np.testing.assert_allclose(D[0], fd, rtol=1e-4, atol=1e-6 * np.max(np.abs(fd)))
    assert res.uncertainty.stderr[0] == pytest.approx(0.01 * np.linalg.norm(fd), rel=1e-4)


def test_log_likelihood_counts_the_readings_at_the_data_times():
    """The negative log-likelihood with known sigma is 1/2 sum (e/sigma)^2 over the fitted
    readings only (not scaled by the data spacing), its gradient by hand."""
    V = _be_states(A_TRUE)[STEPS] + 0.01 * np.sin(np.arange(STEPS.size))[:, None]
    like = _problem(V, STEPS).log_likelihood("standard", 0.02)
    a = 0.7
    value, grad = like.evaluate(np.array([a]))
    e = _be_states(a)[STEPS] - V
    assert like.n_data == e.size
    assert value == pytest.approx(0.5 * np.sum(e**2) / 0.02**2, rel=1e-10)
    de = _be_rate_derivative(a, STEPS)
    assert grad[0] == pytest.approx(np.sum(e * de) / 0.02**2, rel=1e-8)


def test_user_callback_terms_see_the_model_parameters_only():
    """A NonlinearTerm (logistic growth), a LoadTerm.linear source and user coefficients
    (zero-valued, reading eps): their callbacks get
    the model's eps (not the forces), the forces match the data, and the ECFM gradient
    equals central differences; at the parameters that made the data the forces vanish."""

    def res(u, w, e):
        assert len(e) == 3
        return -e[0] * u * (1 - u / e[1])

    def jac(u, w, e):
        return np.array([[-e[0] * (1 - 2 * u[0] / e[1])]])

    def deps(u, w, e):
        return np.array([[-u[0] * (1 - u[0] / e[1]), -e[0] * u[0] ** 2 / e[1] ** 2, 0.0]])

    def c_value(e):  # a user's coefficient: 0 * eps[2] ** 2, its gradient (3,)
        assert len(e) == 3
        return 0.0 * e[2] ** 2

    terms = [
        NonlinearTerm(res, jac, eps_jacobian=deps, degree=2, size=1),
        LoadTerm.linear(np.array([[0.0, 0.0, 1.0]])),
        LinearTerm(np.eye(1), Coefficient(c_value, lambda e: np.zeros(3))),
        LoadTerm.scaled(np.ones(1), Coefficient(c_value, lambda e: np.zeros(3))),
    ]
    system = GalerkinSystem(terms, n_eps=3, Gamma=np.eye(1), M=np.eye(1), name="logistic")
    truth = np.array([1.5, 2.0, 0.1])
    full = march(system, truth, np.array([0.1]), 0.05, 40, tol=1e-13)
    steps = np.array([6, 10, 20, 40])
    prob = DynamicInverseProblem(
        system, [0.1], 0.05, 40, np.eye(1), full.Theta[steps, :, 0], t=0.05 * steps,
        solve_tol=1e-13,
    )  # fmt: skip
    assert prob.loss(truth, "ecfm") < 1e-20
    x = np.array([1.2, 2.4, 0.05])
    z, g, traj = prob.ecfm_objective(x)
    np.testing.assert_allclose(traj.Theta[steps, 0, 0], full.Theta[steps, 0, 0], atol=1e-11)
    h = 1e-6
    fd = [
        (prob.loss(x + h * e, "ecfm") - prob.loss(x - h * e, "ecfm")) / (2 * h) for e in np.eye(3)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-5)


def test_a_force_that_reaches_no_sensor_is_a_convergence_error_naming_gamma():
    terms = [LinearTerm(np.diag(RATES), Coefficient.parameter(0))]
    Gamma = np.array([[1.0, 0.0], [0.0, 0.0]])  # the second force acts nowhere
    system = GalerkinSystem(terms, n_eps=1, Gamma=Gamma, M=np.eye(2))
    V = _be_states(A_TRUE)[STEPS] + 0.01
    prob = DynamicInverseProblem(system, THETA0, DT, N_STEPS, np.eye(2), V, t=DT * STEPS)
    with pytest.raises(ConvergenceError, match="Gamma"):
        prob.ecfm_objective(np.array([0.5]))


def test_covariance_sigma_whitens_the_readings_at_the_data_times():
    """sigma a (C, C) covariance, the same at every data time: the standard fit's stderr is
    1 / |L^-1 J| (Sigma = L L^T, J the closed-form reading derivatives); the ECFM on exact
    data finds the truth through the whitened sensors."""
    cov = np.array([[4e-4, 1e-4], [1e-4, 9e-4]])
    rng = np.random.default_rng(11)
    V = _be_states(A_TRUE)[STEPS] + rng.multivariate_normal(np.zeros(2), cov, STEPS.size)
    res = fit(_problem(V, STEPS), [0.3], sigma=cov)
    assert res.success and res.uncertainty.success
    L = np.linalg.cholesky(cov)
    Jw = np.linalg.solve(L, _be_rate_derivative(res.eps[0], STEPS).T)  # (C, n_t)
    assert res.uncertainty.stderr[0] == pytest.approx(1 / np.linalg.norm(Jw), rel=1e-6)
    exact = fit(_problem(_be_states(A_TRUE)[STEPS], STEPS), [0.3], formulation="ecfm", sigma=cov)
    assert exact.success and exact.eps[0] == pytest.approx(A_TRUE, rel=1e-8)
