"""The pseudo-likelihood layer on the paper's stochastic beam (Section 3.3): moments
against quadrature over deterministic solves, Taylor tests of the gradients of Lambda in
lam and eps, the implicit-function gradient of the inner-outer objective, the
identifiability of the forces, and what SLSQP does with the paper's penalty form."""

import numpy as np
import pytest

from ecfm_uq.chaos import gauss_legendre
from ecfm_uq.inverse import ReplicatedProblem, fit
from ecfm_uq.inverse.formulations.forces import optimal_forces
from ecfm_uq.inverse.problems.pseudo_likelihood import PseudoLikelihood
from ecfm_uq.inverse.statistics.diagnostics import expected_relative_error
from ecfm_uq.problems.beam import BeamModel


@pytest.fixture(scope="module")
def beam():
    model = BeamModel()  # paper: N = M = 6, C = 5 sensors, hat forces
    v = model.sample_data(1.0, 25, rng=0)
    return model, v, PseudoLikelihood(model.system, model.M_obs, v)


def test_moments_match_quadrature_over_deterministic_solves(beam):
    model, v, like = beam
    lam = np.array([3.0, -2.0, 1.0, 0.5, -1.0])
    p = like.evaluate([1.2], lam, order=0)
    om, w = gauss_legendre(40)
    y = np.array([model.M_obs @ model.solve_deterministic(o, 1.2, lam=lam) for o in om.ravel()])
    mean = w @ y
    np.testing.assert_allclose(p.mu, mean, rtol=1e-10)
    # the order-5 PCE variance is a truncation, accurate to ~1e-8 here
    np.testing.assert_allclose(p.var, w @ (y - mean) ** 2, rtol=1e-6)


def test_lambda_gradients_on_the_beam_pass_taylor_test(beam):
    _, _, like = beam
    eps, lam = np.array([0.9]), np.array([2.0, -1.0, 0.5, 1.0, -0.5])
    p = like.evaluate(eps, lam)
    d = np.array([0.3, -0.5, 0.8, 0.1, -0.6])
    for f, g, x, direction, hs in (
        (lambda x: like.value(eps, x), p.grad_lam, lam, d, (1e-1, 5e-2, 2.5e-2)),
        (lambda x: like.value(x, lam), p.grad_eps, eps, np.ones(1), (4e-3, 2e-3, 1e-3)),
    ):
        errs = [
            abs((f(x + h * direction) - f(x - h * direction)) / (2 * h) - g @ direction) for h in hs
        ]
        assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.05)  # error falls like h^2
        assert errs[1] / errs[2] == pytest.approx(4.0, rel=0.05)


def test_inner_outer_gradient_is_the_implicit_function_derivative(beam):
    _, _, like = beam

    def z(e):
        return 0.5 * float(np.sum(optimal_forces(like, [e]).lam ** 2))

    fs = optimal_forces(like, [1.05])
    assert fs.success and fs.min_hess_eig > 0
    g = float(fs.dlam_deps[:, 0] @ fs.lam)
    h = 1e-4
    assert g == pytest.approx((z(1.05 + h) - z(1.05 - h)) / (2 * h), rel=1e-5)


def test_forces_are_weakly_identified_by_the_sensors(beam):
    """The sensor response to the five hat forces is close to rank one (the stiff beam
    filters everything but its first mode), which is why lam*(eps) is large and noisy."""
    model, _, like = beam
    R = np.column_stack(
        [
            model.M_obs @ model.solve_deterministic(0.5, 1.0, lam=np.eye(5)[j])
            - model.M_obs @ model.solve_deterministic(0.5, 1.0)
            for j in range(5)
        ]
    )
    sv = np.linalg.svd(R, compute_uv=False)
    assert sv[0] / sv[-1] > 1e4
    fs = optimal_forces(like, [1.0])
    assert fs.hess_cond > 1e6
    assert np.linalg.norm(fs.lam) > 100  # even at the true load, for D = 25 replicates


def test_standard_estimate_is_close_and_inner_outer_near_the_truth(beam):
    model, v, _ = beam
    bounds = [(0.0, 0.99 * model.beta_min)]
    problem = ReplicatedProblem(model.system, model.M_obs, v)
    std = fit(problem, [0.5], formulation="standard", bounds=bounds)
    io = fit(problem, [0.5], formulation="inner-outer", bounds=bounds)
    assert std.success and io.success, (std.message, io.message)
    assert abs(std.eps[0] - 1.0) < 0.04  # ~3 sd of the standard estimate over seeds
    assert abs(io.eps[0] - 1.0) < 0.35  # ~2 sd of the inner-outer estimate over seeds
    # both reproduce the displacement field to the paper's order (E = 7e-3)
    Theta_true = model.solve(1.0).Theta
    for res in (std, io):
        Theta = model.solve(res.eps[0], res.forces).Theta
        assert expected_relative_error(model.basis, model.chaos, Theta_true, Theta) < 2.1e-2


def test_expected_relative_error_against_a_fine_grid(beam):
    model, _, _ = beam
    A = model.solve(1.0).Theta
    B = model.solve(0.95, [5.0, -3.0, 2.0, 0.0, 1.0]).Theta
    x = np.linspace(0, 1, 1201)
    om = np.linspace(0, 1, 1201)
    u, w = model.displacement(A, x, om), model.displacement(B, x, om)
    want = np.trapezoid(np.trapezoid(np.abs(u - w), om), x) / np.trapezoid(
        np.trapezoid(np.abs(u), om), x
    )
    got = expected_relative_error(model.basis, model.chaos, A, B)
    assert got == pytest.approx(want, rel=1e-5)


def test_penalty_form_stops_at_a_stationary_point_of_an_unbounded_objective(beam):
    model, v, like = beam
    alpha = 100.0
    bounds = [(0.0, 0.99 * model.beta_min)]
    problem = ReplicatedProblem(model.system, model.M_obs, v)
    pen = fit(problem, [0.5], formulation="penalty", bounds=bounds, options={"penalty": alpha})
    io = fit(problem, [0.5], formulation="inner-outer", bounds=bounds)
    std = fit(problem, [0.5], formulation="standard", bounds=bounds)
    lam = pen.forces
    p = like.evaluate(pen.eps, lam)
    # first-order conditions of log(0.5|lam|^2) + alpha Lambda hold at SLSQP's answer ...
    assert abs(p.grad_eps[0]) < 1e-3 * abs(like.evaluate([0.5]).grad_eps[0])
    np.testing.assert_allclose(alpha * p.grad_lam, -lam / (0.5 * lam @ lam), rtol=1e-2)
    # (and so the fit is converged: the objective is flat as the forces are scaled)
    assert abs(2.0 + alpha * lam @ p.grad_lam) < 0.1 and pen.success, pen.message
    # ... its eps is the inner-outer one for this data set ...
    assert abs(pen.eps[0] - io.eps[0]) < 1e-2
    # ... but it is no minimum: shrinking the forces at the standard eps goes lower
    t = 1e-20
    lower = np.log(0.5 * t**2 * lam @ lam) + alpha * like.value(std.eps, t * lam)
    assert lower < pen.loss
