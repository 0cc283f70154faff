"""The time family (``ecfm_uq.system.time``): the method table and its vocabulary, the
``method=``/``scheme=`` spellings, and the forward sensitivities of ``integrate`` against a
closed form (the Fréchet derivative of the matrix exponential) and central differences."""

import numpy as np
import pytest
from _models import burgers_like
from scipy.linalg import expm, expm_frechet

import ecfm_uq.system as system_pkg
from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    adaptive,
    integrate,
    march,
    schemes,
    step_control,
    stepping,
)
from ecfm_uq.system.time import (
    BDF2,
    METHODS,
    BackwardEuler,
    Stepper,
    VariableBDF,
    check_method,
    grids,
)
from ecfm_uq.system.time import integration as integrate_module
from ecfm_uq.system.time import marching as march_module


def _decay_system(N=4, seed=3):
    """:math:`M y' + (10^{\\epsilon_0} K_1 + \\epsilon_1 K_2) y = 0`: both parameters
    inside the operator."""
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((N, N))
    M = np.eye(N) + 0.1 * (B @ B.T)
    A1 = rng.standard_normal((N, N))
    K1 = A1 @ A1.T + N * np.eye(N)
    A2 = rng.standard_normal((N, N))
    K2 = 0.5 * (A2 + A2.T)
    terms = [
        LinearTerm(K1, Coefficient.power10(0, sign=1.0), name="K1"),
        LinearTerm(K2, Coefficient.parameter(1), name="K2"),
    ]
    return GalerkinSystem(terms, 2, M=M, name="decay"), M, K1, K2, rng.standard_normal(N)


def _decay_closed_form(M, K1, K2, y0, eps, t):
    """``y(t) = expm(-M^-1 K t) y0`` and its derivatives in ``eps`` by ``expm_frechet``."""
    K = 10 ** eps[0] * K1 + eps[1] * K2
    dK = [np.log(10.0) * 10 ** eps[0] * K1, K2]
    Minv = np.linalg.inv(M)
    A = -Minv @ K * t
    y = expm(A) @ y0
    dy = np.column_stack([expm_frechet(A, -Minv @ dKi * t, compute_expm=False) @ y0 for dKi in dK])
    return y, dy


def test_the_table_holds_one_stepper_per_method_and_names_it():
    assert set(METHODS) == {"euler", "bdf2", "bdf"}
    assert isinstance(METHODS["euler"], BackwardEuler) and METHODS["euler"].order == 1
    assert isinstance(METHODS["bdf2"], BDF2) and METHODS["bdf2"].order == 2
    assert isinstance(METHODS["bdf"], VariableBDF) and METHODS["bdf"].adaptive
    assert all(isinstance(m, Stepper) and m.name == k for k, m in METHODS.items())
    assert system_pkg.METHODS is METHODS and system_pkg.SCHEMES == ("euler", "bdf2")
    with pytest.raises(NotImplementedError, match="integrate"):
        METHODS["bdf"].rule(0, 0.1)


def test_the_variable_step_bdf2_on_a_uniform_grid_is_the_fixed_step_bdf2():
    dt = 0.1
    times = dt * np.arange(6)
    fixed = METHODS["bdf2"].rules(dt, 5)
    given = METHODS["bdf2"].rules(times=times)
    for (h1, w1), (h2, w2) in zip(fixed, given, strict=True):
        assert h2 == pytest.approx(h1, rel=1e-14)
        np.testing.assert_allclose(w2, w1, rtol=1e-14)
    # the weights are those of the two-step BDF: psi = 4/3 y_s - 1/3 y_{s-1}, h = 2/3 dt
    assert fixed[1][0] == pytest.approx(2 * dt / 3) and fixed[1][1] == pytest.approx(
        (4 / 3, -1 / 3)
    )
    euler = METHODS["euler"].rules(times=[0.0, 0.1, 0.3])
    assert [w for _, w in euler] == [(1.0,), (1.0,)]
    np.testing.assert_allclose([h for h, _ in euler], [0.1, 0.2], rtol=1e-15)


def test_method_is_the_keyword_and_scheme_its_alias():
    system = burgers_like(0)
    args = (system, [1.0], np.sin(np.linspace(0, 3, system.N)), 0.05, 6)
    a = march(*args, method="bdf2", solver={"compiled": False})
    b = march(*args, scheme="bdf2", solver={"compiled": False})
    assert a.scheme == b.scheme == "bdf2"
    np.testing.assert_array_equal(a.Theta, b.Theta)
    assert not np.array_equal(a.Theta, march(*args, solver={"compiled": False}).Theta)
    with pytest.raises(ValueError, match="`method`=.*disagree"):
        march(*args, method="bdf2", scheme="euler")
    with pytest.raises(ValueError, match="`method` must be one of \\('euler', 'bdf2'\\)"):
        march(*args, method="bdf")
    with pytest.raises(ValueError, match="`method` must be one of \\('auto', 'bdf'\\)"):
        integrate(system, [1.0], np.zeros(system.N), [0.0, 0.5], method="euler")
    assert check_method(scheme="euler") == "euler" and check_method() == "euler"


def test_the_old_module_paths_still_import_the_same_objects():
    assert stepping.march is march_module.march is march
    assert adaptive.integrate is integrate_module.integrate is integrate
    assert step_control.choose_steps is grids.choose_steps is system_pkg.choose_steps
    assert schemes.step_rule("bdf2", 1, 0.3) == METHODS["bdf2"].rule(1, 0.3)
    with pytest.raises(ValueError, match="`scheme` must be one of"):
        schemes.check_scheme("rk4")


def test_integrate_sensitivities_match_the_closed_form_of_a_linear_decay():
    system, M, K1, K2, y0 = _decay_system()
    eps = np.array([-0.3, 0.4])
    t_eval = np.array([0.0, 0.05, 0.2, 0.7, 1.5])
    tr = integrate(system, eps, y0, t_eval, rtol=1e-10, sensitivities=True)
    assert tr.success and tr.dTheta.shape == (5, 4, 1, 2)
    np.testing.assert_array_equal(tr.dTheta[0], 0.0)  # Theta0 does not depend on eps
    for k, t in enumerate(t_eval[1:], 1):
        y, dy = _decay_closed_form(M, K1, K2, y0, eps, t)
        np.testing.assert_allclose(tr.Theta[k, :, 0], y, rtol=1e-7, atol=1e-9 * np.abs(y0).max())
        scale = np.abs(dy).max()
        np.testing.assert_allclose(tr.dTheta[k, :, 0], dy, rtol=0, atol=1e-6 * scale)
    # the sensitivities converge with the tolerance: a loose run is farther from the truth
    loose = integrate(system, eps, y0, t_eval, rtol=1e-4, sensitivities=True)
    y, dy = _decay_closed_form(M, K1, K2, y0, eps, t_eval[-1])
    err_tight = np.abs(tr.dTheta[-1, :, 0] - dy).max()
    err_loose = np.abs(loose.dTheta[-1, :, 0] - dy).max()
    assert err_tight < 1e-3 * err_loose
    # a Krylov solver gives the same derivatives (the solve is refined to its residual)
    kr = integrate(system, eps, y0, t_eval, rtol=1e-10, sensitivities=True, solver="gmres")
    np.testing.assert_allclose(kr.dTheta, tr.dTheta, rtol=0, atol=1e-8 * np.abs(tr.dTheta).max())


def _fd(fun, eps, h):
    cols = []
    for i in range(eps.size):
        e = np.zeros_like(eps)
        e[i] = h
        cols.append((fun(eps + e) - fun(eps - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def test_integrate_sensitivities_of_burgers_match_central_differences():
    # nonlinear (convection), the viscosity 10^-eps0 in the operator and the source eps1;
    # the simplified Newton keeps an older Jacobian, the sensitivity solve must not
    model = BurgersModel(n_modes=8, n_steps=10, T=0.4)
    eps = np.array([1.5, 1.0])
    t_eval = np.linspace(0.0, 0.4, 5)

    def states(e, **kw):
        return integrate(model.system, e, model.Theta0, t_eval, rtol=1e-11, **kw)

    tr = states(eps, sensitivities=True)
    assert tr.success and tr.stats["n_sensitivity_solves"] > 0
    np.testing.assert_array_equal(tr.Theta, states(eps).Theta)  # the same steps
    fd = _fd(lambda e: states(e).Theta, eps, 1e-4)
    for i in range(2):  # each parameter in its own units
        err = np.abs(tr.dTheta[..., i] - fd[..., i]).max()
        assert err <= 1e-6 * np.abs(fd[..., i]).max()


def test_integrate_sensitivities_of_a_time_dependent_load():
    # y' = -y + eps0 sin(t): y = eps0 (sin t - cos t + e^-t)/2, dy/deps0 = y / eps0
    system = GalerkinSystem(
        [LinearTerm(np.eye(1)), LoadTerm.scaled(lambda t: np.array([np.sin(t)]),
                                                Coefficient.parameter(0))],
        1,
        M=np.eye(1),
    )  # fmt: skip
    t = np.linspace(0.0, 3.0, 7)
    tr = integrate(system, [2.0], [0.0], t, rtol=1e-10, sensitivities=True)
    exact = (np.sin(t) - np.cos(t) + np.exp(-t)) / 2
    np.testing.assert_allclose(tr.dTheta[:, 0, 0, 0], exact, rtol=1e-7, atol=1e-9)


def test_integrate_sensitivities_of_a_stochastic_burgers_match_central_differences():
    # P > 1 (a random viscosity, chaos order 2): the initial slope solves with M (x) E2;
    # the direct path refines with Newton's older factor, GMRES solves with the new operator
    model = BurgersModel(
        n_modes=5, n_steps=10, T=0.15, viscosity_chaos=ChaosBasis(2), viscosity_spread=0.4
    )
    eps = np.array([1.5, 1.0])
    t_eval = np.linspace(0.0, 0.15, 4)
    for solver in ("dense", "gmres"):

        def states(e, solver=solver, **kw):
            return integrate(model.system, e, model.Theta0, t_eval, rtol=1e-11, solver=solver,
                             **kw)  # fmt: skip

        tr = states(eps, sensitivities=True)
        assert tr.success and tr.dTheta.shape == (4, 5, 3, 2)
        fd = _fd(lambda e, states=states: states(e).Theta, eps, 1e-4)
        for i in range(2):
            err = np.abs(tr.dTheta[..., i] - fd[..., i]).max()
            assert err <= 1e-6 * np.abs(fd[..., i]).max(), (solver, i, err)
