"""Marches on a given, non-uniform grid (``march(..., times=)``) and the error-controlled
grids of ``step_control``: identities with the fixed-step schemes, observed orders against
a closed form, the adjoint against central differences, the local error estimate against
the true local error, and the grid's accuracy against a tight reference."""

import numpy as np
import pytest
from _models import burgers_like

from ecfm_uq.errors import ConvergenceError
from ecfm_uq.problems.pendulum import build_pendulum
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, integrate, march
from ecfm_uq.system.step_control import MAX_RATIO, choose_steps, step_errors

RATE = 1.7


def decay():
    """u' = -10^eps0 u (N = 1, P = 1): u(t) = u0 exp(-10^eps0 t)."""
    return GalerkinSystem([LinearTerm(np.eye(1), Coefficient.power10(0, sign=1.0))], 1, M=np.eye(1))


def graded_grid(n, T, seed):
    """A random grid on [0, T] with step ratios in [1/2, 2]."""
    rng = np.random.default_rng(seed)
    h = np.cumprod(rng.uniform(0.5, 2.0, n))
    return np.concatenate([[0.0], np.cumsum(h / h.sum() * T)])


def subdivide(t, k):
    pieces = [np.linspace(a, b, k + 1)[1:] for a, b in zip(t[:-1], t[1:], strict=True)]
    return np.concatenate([[t[0]], *pieces])


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_a_uniform_grid_marches_as_the_fixed_steps(scheme):
    system, Theta0 = build_pendulum(order=2)
    fixed = march(system, [4.0], Theta0, 0.05, 40, scheme=scheme, tol=1e-13)
    grid = march(system, [4.0], Theta0, times=0.05 * np.arange(41), scheme=scheme, tol=1e-13)
    assert "uniform steps only" in grid.plan.reason
    np.testing.assert_allclose(grid.Theta, fixed.Theta, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("scheme", "order"), [("euler", 1), ("bdf2", 2)])
def test_the_variable_step_schemes_keep_their_order(scheme, order):
    system, eps = decay(), np.log10([RATE])
    t = graded_grid(12, 2.0, seed=3)
    errs = []
    for k in (16, 32, 64):  # asymptotic: the first (Euler) step fades like h^2
        grid = subdivide(t, k)
        tr = march(system, eps, [1.0], times=grid, scheme=scheme, tol=1e-14)
        errs.append(np.abs(tr.Theta[:, 0, 0] - np.exp(-RATE * grid)).max())
    observed = np.log2(np.array(errs[:-1]) / errs[1:])
    np.testing.assert_allclose(observed, order, atol=0.1)


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_adjoint_and_sensitivities_on_a_variable_grid_equal_central_differences(scheme):
    system = burgers_like(2)  # P = 3, a quadratic term
    t = graded_grid(20, 0.5, seed=5)
    Theta0 = np.zeros(system.shape)
    Theta0[:, 0] = 0.1
    W = np.random.default_rng(0).standard_normal((t.size, *system.shape))

    def z(e):
        tr = march(system, e, Theta0, times=t, scheme=scheme, tol=1e-13)
        return float(np.sum(W[1:] * tr.Theta[1:]))

    eps = np.array([1.3])
    tr = march(system, eps, Theta0, times=t, scheme=scheme, tol=1e-13, keep_factors=True,
               sensitivities=True)  # fmt: skip
    g = tr.adjoint_gradient(W)
    h = 1e-5
    fd = (z(eps + h) - z(eps - h)) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-6)
    np.testing.assert_allclose(np.einsum("tikm,tik->m", tr.dTheta[1:], W[1:]), g, rtol=1e-10)


def test_the_bdf2_local_error_estimate_is_the_true_local_error():
    """One variable-step BDF2 step of u' = -a u from the exact history, against the
    estimate from the marched states (rtol negligible, atol = 1: the estimate itself).

    Within 25 % on a graded grid (exact on smooth stretches, up to ~20 % off where the
    step ratio jumps) once the long backward-Euler first step of this grid, whose O(h^2)
    error is not smooth, has left the estimate's window (t > 0.5; the grids of
    choose_steps make that step short instead)."""
    system, eps = decay(), np.log10([RATE])
    t = subdivide(graded_grid(10, 2.0, seed=7), 32)
    tr = march(system, eps, [1.0], times=t, scheme="bdf2", tol=1e-14)
    est = step_errors(tr, 1e-12, 1.0)
    y = np.exp(-RATE * t)
    h = np.diff(t)
    om = h[1:] / h[:-1]
    h_eff = h[1:] * (1 + om) / (1 + 2 * om)
    psi = ((1 + om) ** 2 * y[1:-1] - om**2 * y[:-2]) / (1 + 2 * om)
    true = np.abs(y[2:] - psi / (1 + RATE * h_eff))  # steps 1..n-1
    later = t[2:-1] > 0.5  # the steps 2.. starting after t = 0.5
    np.testing.assert_allclose(est[2:][later], true[1:][later], rtol=0.25)


@pytest.fixture(scope="module")
def pendulum():
    system, Theta0 = build_pendulum(order=3)  # NonlinearTerm, P = 4
    t_data = np.linspace(0.0, 2.0, 9)
    ref = integrate(system, [4.0], Theta0, t_data, rtol=1e-12)
    return system, Theta0, t_data, ref


def test_a_chosen_grid_meets_the_tolerance_holds_the_data_times_and_is_graded(pendulum):
    system, Theta0, t_data, _ = pendulum
    seq = choose_steps(system, [4.0], Theta0, t_data, rtol=1e-4)
    assert seq.met and seq.max_error <= 1.0 and seq.n_steps > 2 * (t_data.size - 1)
    np.testing.assert_array_equal(seq.times[seq.data_index], t_data)
    h = np.diff(seq.times)
    assert (h[1:] / h[:-1]).max() <= MAX_RATIO * (1 + 1e-9)
    # the check is independent of how the grid was made: march it again and estimate
    tr = march(system, [4.0], Theta0, times=seq.times, scheme="bdf2")
    assert step_errors(tr, seq.rtol, seq.atol).max() <= 1.0


def test_a_tighter_tolerance_gives_a_more_accurate_trajectory(pendulum):
    """Against integrate(rtol=1e-12): local control of order 2 makes the global error
    fall about like rtol^(2/3), i.e. at least 10x for 100x in rtol."""
    system, Theta0, t_data, ref = pendulum
    errs = []
    for rtol in (1e-3, 1e-5):
        seq = choose_steps(system, [4.0], Theta0, t_data, rtol=rtol)
        tr = march(system, [4.0], Theta0, times=seq.times, scheme="bdf2", tol=1e-12)
        errs.append(np.abs(tr.Theta[seq.data_index] - ref.Theta).max())
    assert errs[1] < errs[0] / 10


def test_grid_arguments_are_checked():
    system = decay()
    with pytest.raises(ValueError, match="`times` must be strictly increasing"):
        march(system, [0.0], [1.0], times=[0.0, 0.5, 0.5, 1.0])
    with pytest.raises(ValueError, match="pass either `times`"):
        march(system, [0.0], [1.0], 0.1, 10, times=[0.0, 1.0])
    with pytest.raises(ValueError, match="pass `dt` and `n_steps`"):
        march(system, [0.0], [1.0])
    with pytest.raises(ValueError, match="`rtol` must be positive"):
        choose_steps(system, [0.0], [1.0], [0.0, 1.0], rtol=0.0)
    with pytest.raises(ValueError, match="`start` must hold every data time"):
        choose_steps(system, [0.0], [1.0], [0.0, 0.5, 1.0], start=[0.0, 0.4, 1.0])


def test_a_failed_march_reports_the_time_reached():
    """u' = u^2 - u from u(0) = 1.1 blows up at t = ln 11 = 2.40: no grid gets past it."""
    from ecfm_uq.system import NonlinearTerm

    term = NonlinearTerm(
        lambda u, w, e: u * (1 - u), lambda u, w, e: np.array([[1 - 2 * u[0]]]),
        eps_jacobian=lambda u, w, e: np.zeros((1, 1)), size=1,
    )  # fmt: skip
    system = GalerkinSystem([term], 1, M=np.eye(1), name="blow-up")
    with pytest.raises(ConvergenceError, match=r"t=\d"):
        choose_steps(system, [0.0], [1.1], np.linspace(0, 3, 4), max_rounds=6)
