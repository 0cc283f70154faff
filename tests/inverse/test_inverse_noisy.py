"""All-at-once SLSQP inverse problems (Eqs. kpp_inv, ecfm_noise): analytic derivatives
against Taylor remainders, closed-form least squares on a linear model, zero forces for a
consistent model, nonzero forces and feasible moments for a misspecified one, honest
failure reports and bad input."""

import numpy as np
import pytest

from ecfm_uq.inverse import SteadyProblem, fit
from ecfm_uq.inverse.formulations.all_at_once import ConstrainedInverse
from ecfm_uq.inverse.formulations.noise_bounds import consistency_test
from ecfm_uq.problems.fisher_kpp import build_kpp, make_data, sensor_grid
from ecfm_uq.spectral import SineBasis, gaussian_forces, gram, sensor_matrix, stiffness
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm

SIGMA = 0.05


@pytest.fixture(scope="module")
def small_kpp():
    p = build_kpp(n_state=4, n_source=2, sensors=sensor_grid(5))
    d = make_data(p, sigma=SIGMA, seed=1)
    return p, d


def _taylor_ratios(fun, jac, z, dz, hs=(1e-2, 5e-3, 2.5e-3)):
    """First-order Taylor remainders ||f(z + h dz) - f(z) - h J dz|| for decreasing h."""
    f0, J = np.atleast_1d(fun(z)), np.atleast_2d(jac(z))
    errs = [np.linalg.norm(np.atleast_1d(fun(z + h * dz)) - f0 - h * J @ dz) for h in hs]
    return errs, np.linalg.norm(J @ dz)


@pytest.mark.parametrize("formulation", ["standard", "noisy-ecfm"])
def test_analytic_derivatives_taylor(small_kpp, formulation):
    p, d = small_kpp
    prob = ConstrainedInverse(p.system, p.M_obs, d.v, formulation, sigma=SIGMA)
    rng = np.random.default_rng(2)
    z = rng.standard_normal(prob.size)
    dz = rng.standard_normal(prob.size)
    pieces = [
        (prob.objective, prob.objective_grad),
        (prob.equality, prob.equality_jac),
    ]
    if formulation == "noisy-ecfm":
        pieces.append((prob.inequality, prob.inequality_jac))
    for fun, jac in pieces:
        errs, slope = _taylor_ratios(fun, jac, z, dz)
        # all pieces are at most quadratic in z: the remainder is exactly c h^2
        assert slope > 0
        assert errs[0] / errs[1] == pytest.approx(4.0, rel=1e-3)
        assert errs[1] / errs[2] == pytest.approx(4.0, rel=1e-3)


def test_analytic_jacobians_match_central_differences(small_kpp):
    p, d = small_kpp
    prob = ConstrainedInverse(p.system, p.M_obs, d.v, "noisy-ecfm", sigma=SIGMA)
    z = np.random.default_rng(3).standard_normal(prob.size)
    h = 1e-6
    for fun, jac in [(prob.equality, prob.equality_jac), (prob.inequality, prob.inequality_jac)]:
        J = jac(z)
        Jfd = np.column_stack(
            [(fun(z + h * e) - fun(z - h * e)) / (2 * h) for e in np.eye(prob.size)]
        )
        assert np.max(np.abs(J - Jfd)) < 1e-6 * max(1.0, np.max(np.abs(J)))
    g = prob.objective_grad(z)
    gfd = [
        (prob.objective(z + h * e) - prob.objective(z - h * e)) / (2 * h) for e in np.eye(prob.size)
    ]
    assert np.allclose(g, gfd, atol=1e-7)


def _linear_1d(n=8, m=3, C=30, omega=400.0):
    basis, sb = SineBasis(n), SineBasis(m)
    x = np.linspace(0.05, 0.95, C)
    K, F = stiffness(basis), gram(basis, sb)
    system = GalerkinSystem(
        [LinearTerm(K), LoadTerm.linear(F)],
        n_eps=m,
        Gamma=gaussian_forces(basis, x, omega),
        name="heat-1d",
    )
    return system, K, F, sensor_matrix(basis, x)


def test_standard_matches_closed_form_least_squares():
    # linear model theta = K^-1 F eps: the constrained problem is plain least squares
    system, K, F, M_obs = _linear_1d()
    rng = np.random.default_rng(0)
    eps_true = np.array([1.0, -0.5, 0.3])
    v = M_obs @ np.linalg.solve(K, F @ eps_true) + SIGMA * rng.standard_normal(M_obs.shape[0])
    G = M_obs @ np.linalg.solve(K, F)
    eps_ls = np.linalg.lstsq(G, v, rcond=None)[0]
    f_ls = 0.5 * np.sum((G @ eps_ls - v) ** 2)
    res = fit(SteadyProblem(system, M_obs, v), np.zeros(3), method="all-at-once")
    assert res.success, res.message
    assert res.formulation == "standard-slsqp" and res.nit > 0
    # SLSQP stops when the objective changes by less than its ftol (1e-12 by default)
    assert -1e-14 < res.loss - f_ls < 1e-12
    # with a tighter ftol the parameters reach the closed form as closely as the loss can
    # resolve them: f - f_ls = d'(G'G)d / 2 is below round-off of f once
    # |d| < sqrt(2 eps_mach f / lambda_min(G'G)) (7e-8 here), so no minimizer of f in
    # double precision can promise more (scipy >= 1.16's SLSQP stops at 2e-9)
    tight = fit(
        SteadyProblem(system, M_obs, v), np.zeros(3), method="all-at-once",
        options={"ftol": 1e-16},
    )  # fmt: skip
    assert tight.success, tight.message
    resolvable = np.sqrt(2 * np.finfo(float).eps * f_ls / np.linalg.eigvalsh(G.T @ G)[0])
    assert np.max(np.abs(tight.eps - eps_ls)) < resolvable
    assert res.extra["residual_norm"] < 1e-8
    assert res.eps_history.shape[1] == 3 and np.array_equal(res.eps_history[0], np.zeros(3))


def test_consistent_model_needs_no_force():
    system, K, F, M_obs = _linear_1d()
    rng = np.random.default_rng(11)
    v = M_obs @ np.linalg.solve(K, F @ np.array([1.0, -0.5, 0.3]))
    v = v + SIGMA * rng.standard_normal(v.size)
    std = fit(SteadyProblem(system, M_obs, v), np.zeros(3), method="all-at-once")
    # precondition: the least-squares residual of a correct model passes both tests
    assert consistency_test(std.extra["discrepancy"], SIGMA).consistent
    ec = fit(SteadyProblem(system, M_obs, v), np.zeros(3), formulation="noisy-ecfm", sigma=SIGMA)
    assert ec.success, ec.message
    # lam = 0 is feasible, so the minimum force is zero (the misspecified case below
    # needs ||lam|| of order 1 on the same system)
    assert np.linalg.norm(ec.forces) < 1e-6
    assert consistency_test(ec.extra["discrepancy"], SIGMA, rtol=1e-9).consistent


def test_misspecified_model_gets_forces_and_feasible_moments():
    # data from a source with a sin(5 pi x) part that the 3-sine source basis cannot hold
    system, K, F, M_obs = _linear_1d()
    basis = SineBasis(8)
    true_F = gram(basis, SineBasis(5)) @ np.array([1.0, -0.5, 0.3, 0.0, 30.0])
    rng = np.random.default_rng(5)
    v = M_obs @ np.linalg.solve(K, true_F) + SIGMA * rng.standard_normal(M_obs.shape[0])
    std = fit(SteadyProblem(system, M_obs, v), np.zeros(3), method="all-at-once")
    assert consistency_test(std.extra["discrepancy"], SIGMA).var_rejects
    ec = fit(SteadyProblem(system, M_obs, v), np.zeros(3), formulation="noisy-ecfm", sigma=SIGMA)
    assert ec.success, ec.message
    assert np.linalg.norm(ec.forces) > 0.1
    test = consistency_test(ec.extra["discrepancy"], SIGMA, rtol=1e-9)
    assert test.mean_ok and test.var_ok
    assert np.all(ec.extra["inequality"] > -1e-8)
    assert ec.extra["residual_norm"] < 1e-8


def test_slsqp_failure_is_reported_not_hidden(small_kpp):
    p, d = small_kpp
    problem, eps0 = SteadyProblem(p.system, p.M_obs, d.v), np.zeros(p.system.n_eps)
    res = fit(problem, eps0, formulation="noisy-ecfm", sigma=SIGMA, maxiter=2)
    assert not res.success
    assert "Iteration limit" in res.message
    assert res.nit == 2


def test_fd_gradients_option_runs(small_kpp):
    p, d = small_kpp
    problem, eps0 = SteadyProblem(p.system, p.M_obs, d.v), np.zeros(p.system.n_eps)
    a = fit(problem, eps0, method="all-at-once")
    b = fit(problem, eps0, method="all-at-once", options={"jac": "fd"})
    assert a.success and b.success
    assert np.allclose(a.eps, b.eps, rtol=1e-4, atol=1e-4 * np.abs(a.eps).max())
    assert b.nfev > a.nfev


def test_bad_input(small_kpp):
    p, d = small_kpp
    system, _, _, M_obs = _linear_1d()
    problem, eps0 = SteadyProblem(p.system, p.M_obs, d.v), np.zeros(p.system.n_eps)
    with pytest.raises(ValueError, match="sigma"):
        fit(problem, eps0, formulation="noisy-ecfm", sigma=-1.0)
    with pytest.raises(ValueError, match="sigma"):
        fit(problem, eps0, formulation="noisy-ecfm", sigma=0.0)
    with pytest.raises(ValueError, match="alpha"):
        fit(problem, eps0, formulation="noisy-ecfm", sigma=SIGMA, alpha=1.0)
    bad = d.v.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="`v`"):
        SteadyProblem(p.system, p.M_obs, bad)
    with pytest.raises(ValueError, match="`v`"):
        SteadyProblem(p.system, p.M_obs, d.v[:-1])
    with pytest.raises(ValueError, match="M_obs"):
        SteadyProblem(p.system, p.M_obs[:, :-1], d.v)
    with pytest.raises(ValueError, match=r"options\['jac'\]"):
        fit(problem, eps0, method="all-at-once", options={"jac": "exact"})
    with pytest.raises(ValueError, match="maxiter"):
        fit(problem, eps0, method="all-at-once", maxiter=0)
    no_forces = GalerkinSystem(system.terms, n_eps=3)
    with pytest.raises(ValueError, match="Gamma"):
        fit(
            SteadyProblem(no_forces, M_obs, np.zeros(30)),
            np.zeros(3),
            formulation="noisy-ecfm",
            sigma=SIGMA,
        )
    with pytest.raises(ValueError, match="one constraint force per sensor"):
        fit(
            SteadyProblem(system, M_obs[:10], np.zeros(10)),
            np.zeros(3),
            formulation="noisy-ecfm",
            sigma=SIGMA,
        )
    with pytest.raises(ValueError, match="eps"):
        fit(problem, np.zeros(3), method="all-at-once")
