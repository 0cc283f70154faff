"""Dynamic standard/ECFM objectives (Eqs. inv_obj, grad, ecfm_obj, ecfm_grad), Adam and
the finite-difference diagnostics, against Taylor tests and closed forms."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.inverse import fit
from ecfm_uq.inverse.core.finite_differences import fd_gradient
from ecfm_uq.inverse.core.optimizers import adam
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.inverse.statistics.diagnostics import (
    condition_number,
    fd_hessian,
    loss_surface,
    taylor_remainders,
)
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm

TRUE = np.array([1.75, 1.0])


def _problem(model, true_eps=TRUE, tol=1e-12):
    V = model.true_data(true_eps)
    return DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, solve_tol=tol
    )


@pytest.fixture(scope="module")
def burgers():
    return _problem(BurgersModel(n_modes=12, n_steps=20, T=1.0, newton_tol=1e-12))


def _assert_second_order(rem, hs):
    """Remainders fall like h^2: log-log slope close to 2 (a wrong gradient gives 1)."""
    slopes = np.diff(np.log(rem)) / np.diff(np.log(hs))
    assert np.all(slopes > 1.8), slopes
    assert np.all(slopes < 2.2), slopes


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_gradient_taylor_test(burgers, formulation):
    fg = burgers.objective(formulation)
    x = np.array([1.55, 0.7])
    d = np.array([0.6, -0.8])
    hs = np.array([4e-2, 2e-2, 1e-2, 5e-3])
    _assert_second_order(taylor_remainders(fg, x, d, hs), hs)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_gradient_matches_central_differences(burgers, formulation):
    fg = burgers.objective(formulation)
    x = np.array([1.6, 1.3])
    _, g = fg(x)
    h = 1e-5
    fd = [(fg(x + h * e)[0] - fg(x - h * e)[0]) / (2 * h) for e in np.eye(2)]
    np.testing.assert_allclose(g, fd, rtol=1e-6)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_zero_loss_and_gradient_at_truth(burgers, formulation):
    z, g, _ = getattr(burgers, f"{formulation}_objective")(TRUE)
    assert z < 1e-20
    assert np.linalg.norm(g) < 1e-9


def test_objectives_by_definition(burgers):
    """z^INV = dt/2 sum_{i>=1} ||M theta_i - v_i||^2 and z^ECFM = dt/2 sum ||lam_i||^2."""
    x = np.array([1.6, 0.8])
    z, _, tr = burgers.standard_objective(x, gradient=False)
    e = tr.Theta[1:, :, 0] @ burgers.M_obs.T - burgers.V[1:]
    assert z == pytest.approx(0.5 * burgers.dt * np.sum(e**2), rel=1e-14)
    z, _, tr = burgers.ecfm_objective(x, gradient=False)
    assert z == pytest.approx(0.5 * burgers.dt * np.sum(tr.lam[1:] ** 2), rel=1e-14)
    assert burgers.loss(x, "ecfm") == pytest.approx(z, rel=1e-14)


def test_generic_linear_system_taylor_and_closed_form():
    """Not Burgers: a 2-mode linear system theta' + 10^-e1 K theta = e2 b, any system works."""
    K = np.array([[2.0, 0.5], [0.5, 1.0]])
    b = np.array([1.0, -0.5])
    M = np.eye(2)
    Gamma = np.eye(2)
    terms = [
        LinearTerm(K, Coefficient.power10(0, sign=-1.0)),
        LoadTerm.scaled(b, Coefficient.parameter(1)),
    ]
    sysm = GalerkinSystem(terms, n_eps=2, Gamma=Gamma, M=M, name="linear")
    M_obs = np.array([[1.0, 0.0], [0.0, 1.0]])
    dt, n = 0.1, 10
    V = np.zeros((n + 1, 2))
    prob = DynamicInverseProblem(sysm, np.array([1.0, 0.0]), dt, n, M_obs, V)
    x = np.array([0.2, 0.5])
    # ECFM with full observation of zero data: theta_t = 0 for t >= 1, so
    # Gamma lam_1 = -M theta_0 / dt - e2 b and lam_t = -e2 b afterwards (closed form)
    _, _, tr = prob.ecfm_objective(x, gradient=False)
    np.testing.assert_allclose(tr.lam[1], -np.array([1.0, 0.0]) / dt - x[1] * b, atol=1e-12)
    np.testing.assert_allclose(tr.lam[2:], np.tile(-x[1] * b, (n - 1, 1)), atol=1e-12)
    hs = np.array([4e-2, 2e-2, 1e-2, 5e-3])
    for f in ("standard", "ecfm"):
        rem = taylor_remainders(prob.objective(f), x, np.array([0.3, 1.0]), hs)
        # z^ECFM is quadratic in eps2 here and the remainder is exact in h^2
        _assert_second_order(rem, hs)


def test_stochastic_system_gradient_taylor():
    """The objectives act on the mean for P > 1 (random viscosity): gradients still exact."""
    model = BurgersModel(
        n_modes=8, n_steps=10, T=0.5, viscosity_chaos=ChaosBasis(2), viscosity_spread=0.4
    )
    prob = _problem(model)
    x = np.array([1.55, 0.7])
    hs = np.array([4e-2, 2e-2, 1e-2])
    for f in ("standard", "ecfm"):
        _assert_second_order(taylor_remainders(prob.objective(f), x, np.array([1.0, 0.5]), hs), hs)


def test_forward_failure_surfaces():
    # nearly inviscid, huge source, 8 steps over [0, 2]: Newton diverges at step 5
    model = BurgersModel(n_modes=20, n_steps=8, T=2.0)
    prob = _problem(model, tol=1e-10)
    with pytest.raises(ConvergenceError, match=r"eps=.*step 5 .*\|\|R\|\|="):
        prob.standard_objective((8.0, 1e3))
    with pytest.raises(ConvergenceError, match="starting point"):
        fit(prob, (8.0, 1e3), formulation="standard", method="adam", maxiter=3)
    # ECFM: the augmented Newton system fails for absurd data at an absurd eps
    prob0 = DynamicInverseProblem(
        model.system, model.Theta0, 0.25, 1, model.M_obs, np.zeros((2, 4))
    )
    with pytest.raises(ConvergenceError, match=r"ecfm forward solve .*step 1 .*\|\|R\|\|="):
        prob0.ecfm_objective((8.0, 1e3))


def test_adam_stops_with_message_on_failure():
    calls = []

    def fg(x):
        calls.append(x.copy())
        if len(calls) == 4:
            raise ConvergenceError("burgers: Newton failed at step 7 (t=0.14) with ||R||=1e+03")
        return float(x @ x), 2 * x

    res = adam(fg, [1.0, -1.0], lr=0.1, epochs=10)
    assert not res.success
    assert "epoch 3" in res.message and "step 7" in res.message and "||R||" in res.message
    assert res.nit == 2 and res.eps_history.shape == (3, 2)
    np.testing.assert_array_equal(res.eps, calls[2])


def test_adam_closed_form_first_step_and_convergence():
    # bias correction makes the first step exactly lr * sign(g) (up to eps_hat)
    res = adam(lambda x: (float(x @ x), 2 * x), [1.0, -3.0], lr=0.1, epochs=1)
    np.testing.assert_allclose(res.eps_history[1], [0.9, -2.9], rtol=1e-7)
    # a badly scaled quadratic: Adam is scale-free and reaches the minimum
    D = np.array([1e-3, 1e3])
    res = adam(lambda x: (float(0.5 * x @ (D * x)), D * x), [1.0, 1.0], lr=1e-2, epochs=2000)
    assert res.success and np.abs(res.eps).max() < 1e-3
    assert res.loss_history.shape == (2001,) and res.eps_history.shape == (2001, 2)


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        ({"lr": -1.0}, ValueError, "lr"),
        ({"epochs": 0}, ValueError, "epochs"),
        ({"betas": (1.0, 0.9)}, ValueError, "betas"),
        ({"betas": 0.9}, TypeError, "betas"),
        ({"eps_hat": -1.0}, ValueError, "eps_hat"),
    ],
)
def test_adam_bad_input(kw, exc, match):
    with pytest.raises(exc, match=match):
        adam(lambda x: (float(x @ x), 2 * x), [1.0], **kw)


def test_fd_gradient_is_second_order_with_a_step_per_coordinate():
    def f(y):
        return float(np.exp(y[0]) * y[1] ** 2)

    x = np.array([0.1, 0.7])
    exact = np.exp(x[0]) * np.array([x[1] ** 2, 2 * x[1]])
    steps = np.array([1e-2, 3e-2])  # unequal steps: the error of each scales with its own
    e1 = np.abs(fd_gradient(f, x, steps) - exact)
    e2 = np.abs(fd_gradient(f, x, steps / 2) - exact)
    assert np.all((3.5 < e1[0] / e2[0]) & (e1[0] / e2[0] < 4.5))
    assert e2[1] < 1e-12  # y1^2: central differences are exact on a quadratic
    # a scalar step is used for every coordinate
    np.testing.assert_array_equal(fd_gradient(f, x, 1e-2), fd_gradient(f, x, [1e-2, 1e-2]))


def test_fd_hessian_exact_on_quadratic_and_second_order_on_cubic():
    H0 = np.array([[4.0, 1.0], [1.0, 3.0]])

    def fg(x):
        return float(0.5 * x @ H0 @ x + x[0] ** 3), H0 @ x + np.array([3 * x[0] ** 2, 0.0])

    x = np.array([0.3, -0.2])
    exact = H0 + np.diag([6 * x[0], 0.0])
    for kind, fun in (("gradient", fg), ("value", lambda y: fg(y)[0])):
        errs = [np.abs(fd_hessian(fun, x, h, kind=kind) - exact).max() for h in (1e-2, 5e-3)]
        # central differences of a cubic: the only error is round-off (gradient) or
        # tiny; on the quadratic part they are exact
        assert errs[0] < 1e-6, (kind, errs)
    # O(h^2) on a non-polynomial function: exp(x0) x1^2
    f = lambda y: float(np.exp(y[0]) * y[1] ** 2)
    x = np.array([0.1, 0.7])
    ex = np.exp(x[0]) * np.array([[x[1] ** 2, 2 * x[1]], [2 * x[1], 2.0]])
    e1 = np.abs(fd_hessian(f, x, 1e-2, kind="value") - ex).max()
    e2 = np.abs(fd_hessian(f, x, 5e-3, kind="value") - ex).max()
    assert 3.5 < e1 / e2 < 4.5


def test_condition_number():
    assert condition_number(np.diag([1.0, 4.0])) == pytest.approx(4.0)
    R = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    assert condition_number(R @ np.diag([-2.0, 8.0]) @ R.T) == pytest.approx(4.0)
    assert condition_number(np.zeros((2, 2)) + np.diag([1.0, 0.0])) == np.inf
    with pytest.raises(ValueError, match="symmetric"):
        condition_number(np.array([[1.0, 2.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="square"):
        condition_number(np.ones((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        condition_number(np.array([[1.0, np.nan], [np.nan, 1.0]]))
    with pytest.raises(ValueError, match="kind"):
        fd_hessian(lambda x: x, [1.0], kind="forward")
    with pytest.raises(ValueError, match="h"):
        fd_hessian(lambda x: x, [1.0], h=0.0)


def test_loss_surface_masks_failures():
    def f(e):
        if e[0] > 1.5:
            raise ConvergenceError("Newton failed at step 1")
        return float(e @ e)

    Z = loss_surface(f, [1.0, 2.0], [0.0, 1.0, 2.0])
    assert Z.shape == (2, 3)
    np.testing.assert_array_equal(np.ma.getmaskarray(Z)[1], True)
    np.testing.assert_allclose(Z[0].data, [1.0, 2.0, 5.0])


def test_bad_problem_input(burgers):
    sysm = burgers.system
    args = (sysm, burgers.Theta0, burgers.dt, burgers.n_steps, burgers.M_obs)
    with pytest.raises(ValueError, match="`V` must have shape"):
        DynamicInverseProblem(*args, burgers.V[:-1])
    V = burgers.V.copy()
    V[3, 2] = np.nan
    with pytest.raises(ValueError, match="`V` contains NaN"):
        DynamicInverseProblem(*args, V)
    with pytest.raises(ValueError, match="M_obs"):
        DynamicInverseProblem(*args[:4], burgers.M_obs[:, :-1], burgers.V)
    with pytest.raises(ValueError, match="dt"):
        DynamicInverseProblem(sysm, burgers.Theta0, -0.1, burgers.n_steps, burgers.M_obs, burgers.V)
    with pytest.raises(ValueError, match="Theta0"):
        DynamicInverseProblem(sysm, np.zeros(3), burgers.dt, burgers.n_steps, burgers.M_obs, V)
    steady = GalerkinSystem([LinearTerm(np.eye(12))], n_eps=0)
    with pytest.raises(ValueError, match="mass matrix"):
        DynamicInverseProblem(steady, *args[1:], burgers.V)
    with pytest.raises(ValueError, match="formulation"):
        burgers.objective("least-squares")
    # ECFM needs one force per sensor
    two = DynamicInverseProblem(*args[:4], burgers.M_obs[:2], burgers.V[:, :2])
    with pytest.raises(ValueError, match="one constraint force per sensor"):
        two.ecfm_objective(TRUE)
    with pytest.raises(ValueError, match="eps"):
        burgers.standard_objective([1.0])


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_dynamic_uncertainty_derivative_equals_tight_refits(formulation):
    """d eps_hat / dV of the dynamic fits (implicit differentiation of the gradient
    condition) against refits at perturbed data with a tight least-squares optimizer."""
    import scipy.optimize as sopt

    from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=12, n_steps=15, T=0.6)
    V = m.true_data([1.75, 1.0])
    V = V + 0.01 * np.random.default_rng(2).standard_normal(V.shape)

    def refit(data, start):
        # the reference: scipy's trust-region least squares on the trajectory residuals
        # (sqrt(dt) (M theta_t - v_t), or sqrt(dt) lam_t for ECFM) with their forward-
        # sensitivity Jacobian, to round-off; independent of the library's optimizers.
        # (BFGS at gtol 1e-13 stops early on "precision loss" with scipy 1.15.)
        p = DynamicInverseProblem(
            m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, data, solve_tol=1e-13
        )
        w = np.sqrt(m.dt)

        def residual(e):
            traj = p.solve(e, formulation)
            r = traj.lam[1:] if formulation == "ecfm" else p.predictions(traj)[1:] - data[1:]
            return w * r.ravel()

        def jacobian(e):
            traj = p.solve(e, formulation, sensitivities=True)
            if formulation == "ecfm":
                return w * traj.dlam[1:].reshape(-1, e.size)
            dmean = np.einsum("tikm,k->tim", traj.dTheta[1:], m.system.E1)
            return w * np.einsum("cj,tjm->tcm", m.M_obs, dmean).reshape(-1, e.size)

        x = sopt.least_squares(
            residual, start, jac=jacobian, method="trf", x_scale="jac",
            xtol=1e-15, ftol=1e-15, gtol=1e-15,
        ).x  # fmt: skip
        # TRF can stop ~1e-9 short in x (its xtol test); Gauss-Newton steps finish the
        # job while they still lower the gradient (the FD below needs x to ~1e-11)
        r, J = residual(x), jacobian(x)
        for _ in range(20):
            step = np.linalg.lstsq(J, r, rcond=None)[0]
            r1, J1 = residual(x - step), jacobian(x - step)
            if np.linalg.norm(J1.T @ r1) >= np.linalg.norm(J.T @ r):
                break
            x, r, J = x - step, r1, J1
        return x, p

    eps, p = refit(V, np.array([1.75, 1.0]))
    unc = p.uncertainty(eps, formulation, sigma=0.01)
    D = unc.jacobian  # (2, n_steps C), data row-major from t = 1
    assert D.shape == (2, 15 * m.M_obs.shape[0])
    h = 1e-4
    for t, c in [(1, 0), (8, 2), (15, 3)]:
        e = np.zeros_like(V)
        e[t, c] = h
        fd = (refit(V + e, eps)[0] - refit(V - e, eps)[0]) / (2 * h)
        k = (t - 1) * V.shape[1] + c
        np.testing.assert_allclose(D[:, k], fd, rtol=1e-4, atol=1e-6 * np.abs(D).max())
    # sigma given: normal intervals of half-width 1.96 standard errors
    np.testing.assert_allclose(unc.stderr, np.sqrt(np.diag(unc.cov)))
    assert unc.noise_model == "known"
