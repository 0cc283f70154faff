"""The solve plan: one choice of path, solver and preconditioner; one status for every path."""

import numpy as np
import pytest

from ecfm_uq.system import (
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    QuadraticTerm,
    march,
    solve_steady,
    solver_options,
)
from ecfm_uq.system.solve import compiled as compiled_module
from ecfm_uq.system.solve.plan import SolveStatus, krylov_accepts, newton_rtol, plan_solve

N = 6


def _laplacian(n=N):
    return 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)


def _burgers_like(K=None, coef=1.0):
    """A small deterministic system with a quadratic term: the P = 1 kernel takes it."""
    A = np.zeros((N, N, N))
    for i in range(N - 1):
        A[i, i, i + 1] = 0.5
    K = _laplacian() if K is None else K
    terms = [LinearTerm(K, coef), QuadraticTerm(A), LoadTerm.constant(np.ones(N))]
    return GalerkinSystem(terms, n_eps=1, M=np.eye(N))


def test_plan_chooses_path_solver_and_preconditioner_together():
    system = _burgers_like()
    p = plan_solve(system, solver_options(), steady=False)
    assert (p.path, p.solver, p.preconditioner) == ("compiled-p1", "dense", None)
    assert p.label == "dense (compiled)"
    p = plan_solve(system, solver_options(compiled=False), steady=False)
    assert (p.path, p.label) == ("generic", "dense")
    p = plan_solve(system, solver_options(), steady=True)
    assert p.path == "generic"  # steady solves have no kernel
    p = plan_solve(system, solver_options("gmres"), steady=False)
    assert (p.path, p.label) == ("generic", "gmres+mean")


def test_compiled_true_says_why_no_kernel_takes_the_solve():
    system = _burgers_like()
    with pytest.raises(ValueError, match="`compiled`=True.*solver is 'gmres'"):
        march(system, [0.0], np.zeros(N), 0.1, 2, solver={"solver": "gmres", "compiled": True})


def test_solver_options_are_checked_by_name():
    with pytest.raises(ValueError, match="`compiled` must be 'auto', True or False"):
        solver_options(compiled="yes")
    with pytest.raises(ValueError, match="`chord_rate` must lie in \\[0, 1\\]"):
        solver_options(chord_rate=1.5)
    with pytest.raises(TypeError, match="`chord_rate` must be a real number"):
        solver_options(chord_rate="fast")


def test_unavailable_kernels_fall_back_to_the_generic_march(monkeypatch):
    system = _burgers_like()
    args = (system, [0.0], 0.1 * np.sin(np.arange(N)), 0.05, 4)
    fast = march(*args, tol=1e-12, sensitivities=True)
    monkeypatch.setattr(compiled_module, "compiled_kernels", lambda: None)
    slow = march(*args, tol=1e-12, sensitivities=True)
    assert fast.solver == "dense (compiled)" and slow.solver == "dense"
    np.testing.assert_allclose(slow.Theta, fast.Theta, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="do not load"):
        march(*args, solver={"compiled": True})


@pytest.mark.parametrize("compiled", [True, False])
def test_a_singular_step_reports_the_same_status_on_every_path(compiled):
    # K = -M / dt: the backward-Euler step Jacobian M / dt + K (+ the quadratic term at
    # zero) vanishes, whichever path factorizes it
    dt = 0.1
    system = _burgers_like(K=-np.eye(N) / dt)
    tr = march(system, [0.0], np.zeros(N), dt, 3, solver={"compiled": compiled})
    assert not tr.success and tr.failed_step == 1
    assert tr.status == SolveStatus.SINGULAR_JACOBIAN
    assert "singular" in tr.message


@pytest.mark.parametrize("compiled", [True, False])
def test_too_few_iterations_report_max_iterations_on_every_path(compiled):
    system = _burgers_like()
    tr = march(system, [0.0], np.ones(N), 0.1, 3, tol=1e-15, maxiter=1,
               solver={"compiled": compiled})  # fmt: skip
    assert not tr.success and tr.status == SolveStatus.MAX_ITERATIONS
    assert "no convergence in 1 iterations" in tr.message


def test_steady_status():
    system = _burgers_like()
    assert solve_steady(system, [0.0]).status == SolveStatus.CONVERGED
    sol = solve_steady(system, [0.0], tol=1e-300, maxiter=1)
    assert not sol.success and sol.status == SolveStatus.MAX_ITERATIONS
    singular = _burgers_like(K=np.zeros((N, N)))
    sol = solve_steady(singular, [0.0])  # Jacobian zero at the zero start
    assert sol.status == SolveStatus.SINGULAR_JACOBIAN


def test_krylov_acceptance_is_one_rule():
    # every Krylov answer: the true relative residual within 10 rtol
    assert krylov_accepts(1e-9, 1e-10) and not krylov_accepts(1.01e-9, 1e-10)
    assert not krylov_accepts(float("nan"), 1e-10)
    # the inexact-Newton forcing term: a linear residual of 0.05 tol, within [1e-13, 1e-4]
    assert newton_rtol(1.0, 1e-10) == pytest.approx(5e-12, rel=1e-15)
    assert newton_rtol(1e-9, 1e-10) == 1e-4
    assert newton_rtol(1e3, 1e-10) == 1e-13


def test_a_term_binds_as_a_copy_and_is_reusable_at_another_P():
    from ecfm_uq.chaos import ChaosBasis

    K = _laplacian()
    term = LinearTerm(K)
    load = LoadTerm.constant(np.ones(N))
    s2 = GalerkinSystem([term, load], n_eps=0, basis=ChaosBasis(2))
    s4 = GalerkinSystem([term, load], n_eps=0, basis=ChaosBasis(4))
    assert term.G is None  # the caller's term is left unbound
    assert s2.terms[0].G.shape == (3, 3) and s4.terms[0].G.shape == (5, 5)
    assert isinstance(s2.terms, tuple)
    with pytest.raises(AttributeError, match="immutable"):
        s2.terms = ()
    # the same solution as a system built from fresh terms
    fresh = GalerkinSystem([LinearTerm(K), LoadTerm.constant(np.ones(N))], n_eps=0,
                           basis=ChaosBasis(4))  # fmt: skip
    np.testing.assert_array_equal(solve_steady(s4, []).Theta, solve_steady(fresh, []).Theta)
