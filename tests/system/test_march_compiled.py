"""The compiled march (P = 1 dense systems) equals the generic Newton march, with
sensitivities, under the ECFM constraint, with warm starts and for the adjoint."""

import numpy as np
import pytest

from ecfm_uq.errors import ConvergenceError
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import march

EPS = np.array([1.6, 0.9])


@pytest.fixture(scope="module")
def model():
    return BurgersModel(n_modes=16, n_steps=20, T=0.8, viscosity_cells=3)


def _pair(model, **kw):
    args = (model.system, np.array([1.6, 1.5, 1.7, 0.9]), model.Theta0, model.dt, model.n_steps)
    fast = march(*args, tol=1e-12, **kw)
    slow = march(*args, tol=1e-12, solver="sparse-direct", **kw)  # the generic Newton path
    return fast, slow


@pytest.mark.parametrize("constrained", [False, True])
def test_compiled_march_equals_the_generic_path(model, constrained):
    kw = {"sensitivities": True}
    if constrained:
        V = np.tile(model.M_obs @ model.theta0, (model.n_steps + 1, 1)) * 0.9
        kw["constraint"] = (model.M_obs, V)
    fast, slow = _pair(model, **kw)
    assert fast.solver == "dense (compiled)" and slow.solver == "sparse-direct"
    assert fast.success and slow.success
    np.testing.assert_array_equal(fast.nit, slow.nit)
    np.testing.assert_allclose(fast.Theta, slow.Theta, rtol=0, atol=1e-11)
    np.testing.assert_allclose(fast.dTheta, slow.dTheta, rtol=0, atol=1e-9)
    if constrained:
        np.testing.assert_allclose(fast.lam, slow.lam, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fast.dlam, slow.dlam, rtol=0, atol=1e-8)


def test_compiled_adjoint_and_warm_start(model):
    rng = np.random.default_rng(0)
    g = rng.standard_normal((model.n_steps + 1, model.system.N, 1))
    fast, slow = _pair(model, keep_factors=True)
    np.testing.assert_allclose(fast.adjoint_gradient(g), slow.adjoint_gradient(g), rtol=1e-9)
    # a warm start from a nearby trajectory: fewer Newton iterations, same states
    eps = np.array([1.6, 1.5, 1.7, 0.9])
    near = march(model.system, eps + 0.01, model.Theta0, model.dt, model.n_steps, tol=1e-12)
    warm = march(model.system, eps, model.Theta0, model.dt, model.n_steps, tol=1e-12, guess=near)
    np.testing.assert_allclose(warm.Theta, fast.Theta, rtol=0, atol=1e-11)
    assert warm.nit.sum() < fast.nit.sum()
    with pytest.raises(ValueError, match="`guess` must be a Trajectory"):
        march(model.system, eps, model.Theta0, model.dt, 5, guess=near)


def test_compiled_failure_is_reported(model):
    eps = np.array([1.6, 1.5, 1.7, 0.9])
    bad = march(model.system, eps, model.Theta0, model.dt, model.n_steps, tol=1e-14, maxiter=1)
    assert not bad.success and bad.failed_step == 1
    assert "Newton failed at step 1" in bad.message and "no convergence in 1" in bad.message
    assert len(bad.times) == 1  # no unconverged state is returned
    with pytest.raises(ConvergenceError, match="Newton failed at step 1"):
        march(model.system, eps, model.Theta0, model.dt, 3, tol=1e-14, maxiter=1, strict=True)


def test_parameter_dependent_quadratic_coefficient(model):
    """dR/deps of c(eps) q(theta) is q gradc^T: sensitivities and the adjoint of the
    compiled march against central differences of the march itself."""
    from ecfm_uq.system import Coefficient, GalerkinSystem, QuadraticTerm

    base = model.system
    conv = [t for t in base.terms if isinstance(t, QuadraticTerm)][0]
    terms = [QuadraticTerm(conv.form, Coefficient.power10(3, sign=1.0), name="convection")]
    terms += [t for t in base.terms if t is not conv]
    system = GalerkinSystem(terms, n_eps=base.n_eps, basis=base.basis, M=base.M)
    eps = np.array([1.6, 1.5, 1.7, -0.2])
    args = (system, eps, model.Theta0, model.dt, model.n_steps)
    tr = march(*args, tol=1e-12, sensitivities=True, keep_factors=True)
    assert tr.solver == "dense (compiled)"
    h = 1e-6
    fd = np.stack(
        [
            (
                march(system, eps + h * e, *args[2:], tol=1e-13).Theta
                - march(system, eps - h * e, *args[2:], tol=1e-13).Theta
            )
            / (2 * h)
            for e in np.eye(4)
        ],
        axis=-1,
    )
    scale = np.abs(fd).max()
    np.testing.assert_allclose(tr.dTheta, fd, rtol=0, atol=1e-7 * scale)
    g = np.random.default_rng(1).standard_normal(tr.Theta.shape)
    forward = np.einsum("tipm,tip->m", tr.dTheta[1:], g[1:])
    np.testing.assert_allclose(tr.adjoint_gradient(g), forward, rtol=1e-9)


def test_generic_march_takes_over_when_the_kernels_are_unavailable(model):
    # numba's LAPACK binding is numba-internal; without it the generic path answers
    args = (model.system, np.array([1.6, 1.5, 1.7, 0.9]), model.Theta0, model.dt, 5)
    fast = march(*args, tol=1e-12, sensitivities=True)
    slow = march(*args, tol=1e-12, sensitivities=True, solver={"compiled": False})
    assert fast.solver == "dense (compiled)" and slow.solver == "dense"
    np.testing.assert_allclose(slow.Theta, fast.Theta, rtol=0, atol=1e-11)
    np.testing.assert_allclose(slow.dTheta, fast.dTheta, rtol=0, atol=1e-9)
