"""The Galerkin ECFM on the data's time scale: an adaptive (frozen, error-controlled) grid
between data times off any dt grid, and the force bases ("constant", "linear", RBF).
Against the ODE's closed form, marches of known sources on the frozen grid, an
independently assembled minimum-norm solve, quadrature of the Gram matrices, and central
differences."""

import numpy as np
import pytest
from scipy.integrate import quad

from ecfm_uq.inverse import fit
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.inverse.problems.force_bases import basis_matrix, gram
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, march

RATES = np.array([1.0, 2.5])  # theta_i' = -a k_i theta_i (+ a source)
THETA0 = np.array([1.0, -0.7])
A_TRUE = 0.8
T_DATA = np.array([0.3, 0.7, 1.1, 1.6, 2.0])  # on no dt grid of the problem (dt = 0.25)


def _system(load=None):
    terms = [LinearTerm(np.diag(RATES), Coefficient.parameter(0))]
    if load is not None:
        terms.append(load)
    return GalerkinSystem(terms, n_eps=1, Gamma=np.eye(2), M=np.eye(2), name="decay")


def _exact(a, t):
    return THETA0 * np.exp(-a * RATES * np.asarray(t)[:, None])


def _problem(V, rtol=1e-6, **kw):
    return DynamicInverseProblem(
        _system(), THETA0, 0.25, 8, np.eye(2), V, t=T_DATA, scheme="adaptive", rtol=rtol,
        atol=rtol * 1e-2, solve_tol=1e-13, **kw,
    )  # fmt: skip


def _on_grid_data(problem, a, load=None):
    """Readings at the data times of a march of the (sourced) model on the frozen grid."""
    traj = march(
        _system(load), np.array([a]), THETA0, times=problem.steps.times, scheme="bdf2",
        tol=1e-14,
    )  # fmt: skip
    return traj.Theta[problem.steps.data_index[1:], :, 0]


def _central(f, a, h=1e-5):
    return (f(np.array([a + h])) - f(np.array([a - h]))) / (2 * h)


@pytest.mark.slow
def test_adaptive_ecfm_estimate_converges_to_the_ode_value_as_rtol_shrinks():
    """Exact-ODE readings at off-grid times: the ECFM estimate's error falls with rtol
    (measured: 1.6e-4 at rtol=1e-5, 5.6e-6 at rtol=1e-7)."""
    V = _exact(A_TRUE, T_DATA)
    errors = []
    for rtol in (1e-5, 1e-7):
        res = fit(_problem(V, rtol), [0.5], formulation="ecfm", uncertainty=False)
        assert res.success and res.extra["steps"]["met"]
        errors.append(abs(res.eps[0] - A_TRUE))
    assert errors[1] < errors[0] / 10
    assert errors[1] < 1e-5


def test_adaptive_ecfm_zero_forces_on_exact_data_and_a_missing_source_in_its_interval():
    prob = _problem(_exact(A_TRUE, T_DATA))
    prob.freeze_steps([A_TRUE])
    assert np.all(np.isin(T_DATA, prob.steps.times))  # the data times are grid nodes
    clean = _problem(_exact(A_TRUE, T_DATA))
    clean.steps, clean._rows = prob.steps, prob.steps.data_index
    clean.V = np.vstack([clean.V[:1], _on_grid_data(prob, A_TRUE)])
    z, _, traj = clean.ecfm_objective([A_TRUE])
    assert z < 1e-24 and np.abs(traj.lam).max() < 1e-11
    # a source f on the third data interval (1.1 - 0.7] only (read at the step ends)
    f = np.array([0.4, -0.3])
    source = LoadTerm(lambda e, t: f * (0.7 < t <= 1.1 + 1e-12), name="source")
    clean.V = np.vstack([clean.V[:1], _on_grid_data(prob, A_TRUE, source)])
    clean.forget_solves()
    _, lam, _, _ = clean._interval_forces(np.array([A_TRUE]))
    expected = np.zeros((5, 2))
    expected[2] = f
    np.testing.assert_allclose(lam, expected, atol=1e-10)


@pytest.mark.parametrize("basis", ["constant", "linear", {"rbf": 0.4}])
def test_adaptive_ecfm_gradients_against_central_differences(basis):
    V = _exact(A_TRUE, T_DATA) + 0.01 * np.cos(np.arange(5))[:, None]
    prob = _problem(V, force_basis=basis)
    prob.freeze_steps([0.7])
    a = 0.6
    z, g, _ = prob.ecfm_objective(np.array([a]))
    fd = _central(lambda e: prob.ecfm_objective(e, gradient=False)[0], a)
    assert g[0] == pytest.approx(fd, rel=1e-6)
    r, J, _ = prob.residual(np.array([a]), "ecfm")
    assert 0.5 * r @ r == pytest.approx(z, rel=1e-12)
    assert (J.T @ r)[0] == pytest.approx(g[0], rel=1e-8)  # the Gauss-Newton gradient exact
    if basis == "constant":  # one force per interval: the residual Jacobian exact too
        Jfd = _central(lambda e: prob.residual(e, "ecfm")[0], a)
        np.testing.assert_allclose(J[:, 0], Jfd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("basis", ["linear", {"rbf": 0.3}])
def test_more_basis_functions_than_intervals_give_the_minimum_norm_forces(basis):
    """The model is linear in the forces: the match is A lam = v - theta_free, A assembled
    here column by column by marching each basis function as a known load; the minimum
    W-norm solution by an SVD least-squares solve of the whitened system."""
    V = _exact(A_TRUE, T_DATA) + 0.02 * np.sin(np.arange(5))[:, None]
    prob = _problem(V, force_basis=basis)
    prob.freeze_steps([A_TRUE])
    a = np.array([0.7])
    _, lam, _, _ = prob._interval_forces(a)
    forces = prob._forces
    grid, rows = prob.steps.times, prob.steps.data_index
    E = forces.E

    def readings(load):
        th = march(_system(load), a, THETA0, times=grid, scheme="bdf2", tol=1e-14).Theta
        return th[rows[1:], :, 0].ravel()

    free = readings(None)
    zero_start = np.zeros_like(THETA0)
    cols = []
    for j in range(forces.B):
        for c in range(2):

            def F(e, t, j=j, c=c):
                k = int(np.argmin(np.abs(grid - t)))
                return E[k, j] * np.eye(2)[c]

            th = march(_system(LoadTerm(F)), a, zero_start, times=grid, scheme="bdf2", tol=1e-14)
            cols.append(th.Theta[rows[1:], :, 0].ravel())
    A = np.array(cols).T
    b = V.ravel() - free
    L = np.linalg.cholesky(forces.W)  # W = L L^T: lam = L^-T y, y the min-norm solution
    y = np.linalg.lstsq(A @ np.linalg.inv(L.T), b, rcond=None)[0]
    np.testing.assert_allclose(lam.ravel(), np.linalg.solve(L.T, y), rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("kind,width", [("linear", None), ("rbf", 0.35)])
def test_gram_matrices_against_quadrature(kind, width):
    knots = np.r_[0.0, T_DATA]
    G = gram(kind, width, knots)
    for i, j in [(0, 0), (1, 2), (2, 2), (0, 5), (4, 5)]:

        def phi(t, i=i, j=j):
            row = basis_matrix(kind, width, knots, [t])[0]
            return row[i] * row[j]

        val = quad(phi, knots[0], knots[-1], points=knots, limit=200)[0]
        assert G[i, j] == pytest.approx(val, rel=1e-9, abs=1e-13)


def test_force_basis_as_a_fit_option():
    t = np.array([0.4, 0.8, 1.2, 1.6, 2.0])  # on the dt grid: backward Euler, fixed steps
    V = _exact(A_TRUE, t) + 0.01 * np.cos(np.arange(5))[:, None]

    def problem(**kw):
        return DynamicInverseProblem(_system(), THETA0, 0.1, 20, np.eye(2), V, t=t, **kw)

    prob = problem()
    res = fit(prob, [0.5], formulation="ecfm", options={"force_basis": "linear"})
    assert res.success and prob.force_basis == "constant"  # the problem is not changed
    other = fit(problem(force_basis="linear"), [0.5], formulation="ecfm")
    assert res.eps[0] == pytest.approx(other.eps[0], rel=1e-8)
    with pytest.raises(ValueError, match="force_basis"):
        fit(prob, [0.5], formulation="ecfm", options={"force_basis": "quadratic"})
    with pytest.raises(ValueError, match="has no forces"):
        fit(prob, [0.5], options={"force_basis": "linear"})


def test_a_smooth_missing_source_is_recovered_better_by_linear_and_rbf_bases():
    """A sinusoidal source, readings every 10 steps of backward Euler (exact data of the
    sourced march): the L2 error of the ECFM force function against the known source
    (measured: constant 0.081, linear 0.018, RBF of width 0.2 0.015; the source's L2 0.55)."""
    dt, n, every = 0.02, 100, 10

    def f(t):
        return np.array([0.5 * np.sin(2 * t), 0.3 * np.cos(3 * t)])

    load = LoadTerm(lambda e, t: f(t), name="source")
    sourced = march(_system(load), np.array([A_TRUE]), THETA0, dt, n, tol=1e-14)
    steps = np.arange(every, n + 1, every)
    V = sourced.Theta[steps, :, 0]
    truth = np.array([f(t) for t in dt * np.arange(1, n + 1)])
    err = {}
    for name, basis in [("constant", "constant"), ("linear", "linear"), ("rbf", {"rbf": 0.2})]:
        prob = DynamicInverseProblem(
            _system(), THETA0, dt, n, np.eye(2), V, t=dt * steps, solve_tol=1e-13,
            force_basis=basis,
        )  # fmt: skip
        traj = prob.ecfm_objective(np.array([A_TRUE]), gradient=False)[2]
        err[name] = np.sqrt(dt * np.sum((traj.lam[1:] - truth) ** 2))
        readings = traj.Theta[steps, :, 0]
        np.testing.assert_allclose(readings, V, atol=1e-11)  # the exact match
    assert err["linear"] < 0.3 * err["constant"]
    assert err["rbf"] < 0.3 * err["constant"]


def test_too_wide_gaussians_are_refused_by_name():
    t = np.array([0.4, 0.8, 1.2, 1.6, 2.0])
    prob = DynamicInverseProblem(
        _system(), THETA0, 0.1, 20, np.eye(2), _exact(A_TRUE, t), t=t, force_basis={"rbf": 5.0}
    )
    with pytest.raises(ValueError, match=r"`force_basis` \{'rbf': 5\}.*numerically dependent"):
        prob.ecfm_objective([0.7])


@pytest.mark.parametrize("basis", ["linear", {"rbf": 0.25}])
def test_burgers_minimum_norm_forces_match_and_their_gradient_is_exact(basis):
    """A nonlinear model (Burgers, 12 modes), data every 5th step, more basis functions
    than intervals: the match holds and the objective's gradient (the multipliers'
    envelope derivative) agrees with central differences."""
    model = BurgersModel(n_modes=12, n_steps=20, T=1.0, newton_tol=1e-12)
    steps = np.arange(5, 21, 5)
    V = model.true_data(np.array([1.75, 1.0]))[steps]
    V = V + 0.01 * np.cos(np.arange(V.size)).reshape(V.shape)
    prob = DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V,
        t=model.dt * steps, solve_tol=1e-12, force_basis=basis,
    )  # fmt: skip
    x = np.array([1.6, 0.8])
    _, g, traj = prob.ecfm_objective(x)
    np.testing.assert_allclose(traj.Theta[steps, :, 0] @ model.M_obs.T, V, atol=1e-10)
    h = 1e-5
    fd = [
        (prob.loss(x + h * e, "ecfm") - prob.loss(x - h * e, "ecfm")) / (2 * h) for e in np.eye(2)
    ]
    np.testing.assert_allclose(g, fd, rtol=1e-6)
