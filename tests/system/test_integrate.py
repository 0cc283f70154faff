"""Adaptive ``integrate``: closed forms, a tight scipy reference of the same Galerkin system,
honest failure and clear errors."""

import numpy as np
import pytest
from _models import burgers_like, diffusion
from scipy import stats
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from ecfm_uq.chaos import Inputs, input_basis, input_coefficients, input_gram
from ecfm_uq.problems.pendulum import build_pendulum
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, NonlinearTerm, integrate
from ecfm_uq.system.model.thresholds import SolveStatus

T_GRID = np.linspace(0.0, 10.0, 1000)


def _decay_moments(t):
    """Closed-form mean and variance of u = alpha exp(-beta t), alpha ~ N(1.5, 0.2^2),
    beta ~ U(0.1, 0.2) independent (chaospy's intrusive Galerkin tutorial)."""
    t = np.asarray(t, dtype=float)
    safe = np.where(t > 0, t, 1.0)

    def mgf(k):  # E[exp(-k beta t)]
        return np.where(
            t > 0, (np.exp(-0.1 * k * safe) - np.exp(-0.2 * k * safe)) / (0.1 * k * safe), 1.0
        )

    mean = 1.5 * mgf(1)
    return mean, (1.5**2 + 0.2**2) * mgf(2) - mean**2


def test_exponential_decay_tutorial_at_order_5_within_1e_8_of_the_closed_form():
    # the recipe of docs/time.md, no germ coordinate by hand
    inputs = Inputs([stats.norm(1.5, 0.2), stats.uniform(0.1, 0.1)], names=["alpha", "beta"])
    basis = input_basis(inputs, 5)
    G = input_gram(basis, inputs, lambda x: x[:, 1])
    c0 = input_coefficients(basis, inputs, lambda x: x[:, 0])
    system = GalerkinSystem([LinearTerm(np.eye(1), G=G)], 0, basis=basis, M=np.eye(1))
    tr = integrate(system, [], c0[None, :], T_GRID, rtol=1e-10)
    assert tr.success and tr.Theta.shape == (1000, 1, basis.size)
    mean, var = _decay_moments(T_GRID)
    Th = tr.Theta[:, 0, :]
    assert np.abs(Th @ system.E1 - mean).max() < 1e-8
    assert (
        np.abs(np.einsum("tk,kl,tl->t", Th, system.E2, Th) - (Th @ system.E1) ** 2 - var).max()
        < 1e-8
    )
    assert tr.stats["n_steps"] < 1000  # steps chosen by the error, not by the grid


def _pendulum_reference(system, eps, Theta0, t_eval):
    """The same Galerkin ODE by scipy's DOP853 (order 8; the pendulum is not stiff) at
    rtol 1e-13."""

    def f(t, y):
        return -system.residual(y.reshape(system.shape), eps).ravel()

    sol = solve_ivp(f, (t_eval[0], t_eval[-1]), Theta0.ravel(), method="DOP853",
                    rtol=1e-13, atol=1e-15, t_eval=t_eval)  # fmt: skip
    return sol.y.T.reshape(len(t_eval), *system.shape)


@pytest.mark.parametrize("order", [0, 3])
def test_pendulum_within_1e_6_of_a_tight_reference_at_rtol_1e_8(order):
    system, Theta0 = build_pendulum(order=order)
    t_eval = np.linspace(0.0, 5.0, 51)
    ref = _pendulum_reference(system, [4.0], Theta0, t_eval)
    tr = integrate(system, [4.0], Theta0, t_eval, rtol=1e-8)
    assert tr.success and tr.scheme == "bdf"
    assert np.abs(tr.Theta - ref).max() < 1e-6
    # looser tolerance, larger error, fewer steps: the control does something
    loose = integrate(system, [4.0], Theta0, t_eval, rtol=1e-4)
    assert loose.stats["n_steps"] < tr.stats["n_steps"] / 3
    assert np.abs(loose.Theta - ref).max() > np.abs(tr.Theta - ref).max()


def test_sparse_diffusion_with_krylov_solves_and_a_time_grid_not_starting_at_t0():
    system, _ = diffusion(N=30, dim=2, order=2, sparse=True)
    eps, t_eval = [0.0, 1.0], np.linspace(0.005, 0.05, 10)
    # the exact solution from zero of y' = A y + b (M = I / 31): exp(t [[A, b], [0, 0]])
    n = system.N * system.P
    E = np.zeros((n + 1, n + 1))
    E[:n, :n] = -31.0 * system.jacobian(system.zeros(), eps)
    E[:n, n] = -31.0 * system.residual(system.zeros(), eps).ravel()
    ref = np.array([expm(t * E)[:n, n] for t in t_eval]).reshape(10, *system.shape)
    tr = integrate(system, eps, np.zeros(system.shape), t_eval, t0=0.0, rtol=1e-8,
                   atol=1e-12, solver="cg")  # fmt: skip
    assert tr.success and tr.solver.startswith("cg")
    assert np.abs(tr.Theta - ref).max() < 1e-6 * np.abs(ref).max()


def test_a_blow_up_returns_an_honest_failure_with_the_time_reached():
    # u' = u^2, u(0) = 1: u = 1 / (1 - t) blows up at t = 1
    blowup = NonlinearTerm(lambda u, w, e: -(u**2), lambda u, w, e: np.diag(-2 * u), size=1)
    system = GalerkinSystem([blowup], 0, M=np.eye(1))
    t_eval = np.linspace(0.0, 2.0, 41)
    tr = integrate(system, [], np.ones(1), t_eval, rtol=1e-8)
    assert not tr.success and tr.status == SolveStatus.STEP_SIZE
    reached = tr.stats["t_reached"]
    assert 0.99 < reached <= 1.0 and f"t={reached:.6g}" in tr.message
    assert np.all(tr.times < 1.0) and len(tr.times) == 20
    # the states returned are converged ones: errors of rtol = 1e-8 amplified by the
    # blow-up's own growth, (1 - t)^-2 = 400 at t = 0.95
    np.testing.assert_allclose(tr.Theta[:, 0, 0], 1 / (1 - tr.times), rtol=1e-8 * 400 * 10)


def test_max_steps_gives_a_failed_result_not_an_exception():
    system, Theta0 = build_pendulum(order=0)
    tr = integrate(system, [4.0], Theta0, np.linspace(0, 5, 11), rtol=1e-8, max_steps=20)
    assert not tr.success and "max_steps=20" in tr.message
    assert 0 < len(tr.times) < 11


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rtol": 0.0}, "`rtol` must be positive"),
        ({"rtol": -1e-6}, "`rtol` must be positive"),
        ({"rtol": 1e-17}, "below what double precision"),
        ({"method": "rk45"}, "`method` must be one of"),
        ({"atol": -1.0}, "`atol` must be a non-negative"),
        ({"t_eval": [0.0, 1.0, 1.0]}, "`t_eval` must be strictly increasing"),
        ({"t_eval": [0.0, 2.0, 1.0]}, "sort it"),
        ({"t_eval": [0.0, 1.0], "t0": 0.5}, "start at or after t0"),
    ],
)
def test_bad_arguments_are_named(kwargs, match):
    system, Theta0 = build_pendulum(order=0)
    args = {"t_eval": np.linspace(0, 1, 5), **kwargs}
    t_eval = args.pop("t_eval")
    with pytest.raises(ValueError, match=match):
        integrate(system, [4.0], Theta0, t_eval, **args)


def test_a_system_without_mass_matrix_is_refused():
    system = GalerkinSystem([LinearTerm(np.eye(2))], 0)
    with pytest.raises(ValueError, match="no mass matrix"):
        integrate(system, [], np.ones(2), [0.0, 1.0])


def test_a_quadratic_term_with_a_random_viscosity_and_a_load():
    system = burgers_like(2)
    t_eval = np.linspace(0.0, 0.5, 11)

    def f(t, y):
        return -system.residual(y.reshape(system.shape), [1.2]).ravel()

    def jac(t, y):  # speeds Radau's Newton up; its answer is set by f
        return -system.jacobian(y.reshape(system.shape), [1.2])

    sol = solve_ivp(f, (0.0, 0.5), np.zeros(system.N * system.P), method="Radau", rtol=1e-13,
                    atol=1e-15, t_eval=t_eval, jac=jac)  # fmt: skip
    ref = sol.y.T.reshape(11, *system.shape)
    tr = integrate(system, [1.2], np.zeros(system.shape), t_eval, rtol=1e-9, atol=1e-12)
    assert tr.success and tr.stats["n_jacobians"] < tr.stats["n_steps"]  # Jacobians reused
    assert np.abs(tr.Theta - ref).max() < 1e-6 * np.abs(ref).max()


def test_a_model_that_cannot_be_evaluated_past_some_state_fails_honestly():
    # u' = u from 1, but the model returns NaN once u > 2 (at t = ln 2)
    def residual(u, w, e):
        return np.where(u > 2.0, np.nan, -u)

    term = NonlinearTerm(residual, lambda u, w, e: -np.eye(1), size=1)
    system = GalerkinSystem([term], 0, M=np.eye(1))
    tr = integrate(system, [], np.ones(1), np.linspace(0.0, 1.0, 11), rtol=1e-8)
    assert not tr.success and "t=0.69" in tr.message
    assert np.all(tr.times < np.log(2.0)) and len(tr.times) == 7
    np.testing.assert_allclose(tr.Theta[:, 0, 0], np.exp(tr.times), rtol=1e-6)


def test_a_zero_start_with_a_load_that_ramps_up_from_zero():
    # u' = t from u(0) = 0: zero state and zero slope at t0; u = t^2 / 2
    ramp = LoadTerm(lambda e, t: np.array([t]))
    system = GalerkinSystem([LinearTerm(np.zeros((1, 1))), ramp], 0, M=np.eye(1))
    t_eval = np.linspace(0.0, 2.0, 5)
    tr = integrate(system, [], np.zeros(1), t_eval, rtol=1e-8)
    assert tr.success
    np.testing.assert_allclose(tr.Theta[:, 0, 0], t_eval**2 / 2, rtol=1e-7, atol=1e-15)
