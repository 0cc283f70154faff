"""Steady standard and ECFM inverse problems (``fit`` of a ``SteadyProblem``) on a linear
model with a known answer, and their gradients against central differences."""

import numpy as np
import pytest

from ecfm_uq.inverse import SteadyProblem, ecfm_objective, fit, standard_objective
from ecfm_uq.spectral import SineBasis, hat_forces, load, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
K = stiffness(B)
F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
SENS = np.array([0.2, 0.4, 0.6, 0.8])
M_OBS = sensor_matrix(B, SENS)


def heat(conductivity_param=False):
    """-k w'' = eps0 + eps1 x, optionally with k = 10^eps2."""
    coef = Coefficient.power10(2, sign=1.0) if conductivity_param else 1.0
    n_eps = 3 if conductivity_param else 2
    B3 = np.column_stack([F, np.zeros(B.size)]) if conductivity_param else F
    return GalerkinSystem(
        [LinearTerm(K, coef), LoadTerm.linear(B3)], n_eps, Gamma=hat_forces(B, SENS, 0.2)
    )


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_recovers_true_parameters_from_consistent_data(formulation):
    system = heat()
    true = np.array([3.0, -2.0])
    v = M_OBS @ solve_steady(system, true).Theta[:, 0]
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation=formulation)
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, true, rtol=1e-7)
    assert res.loss < 1e-14
    assert res.eps_history.shape[1] == 2 and res.loss_history[0] > res.loss_history[-1]


def test_ecfm_forces_are_nonzero_for_misspecified_data():
    system = heat()
    # data from a source outside the model family (a point-like bump)
    bump = load(B, lambda x: 50 * np.exp(-200 * (x - 0.55) ** 2))
    v = M_OBS @ np.linalg.solve(K, F @ [3.0, -2.0] + bump)
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation="ecfm")
    assert res.success
    assert np.linalg.norm(res.forces) > 1.0


@pytest.mark.parametrize("objective", [standard_objective, ecfm_objective])
def test_objective_gradients_against_central_differences(objective):
    system = heat(conductivity_param=True)
    v = M_OBS @ solve_steady(system, [3.0, -2.0, 0.1]).Theta[:, 0] + np.array([0.01, 0, -0.02, 0.0])
    eps = np.array([2.0, -1.0, 0.3])
    _, g, _ = objective(system, M_OBS, v, eps)
    h = 1e-6
    fd = []
    for m in range(3):
        e = np.zeros(3)
        e[m] = h
        fd.append(
            (objective(system, M_OBS, v, eps + e)[0] - objective(system, M_OBS, v, eps - e)[0])
            / (2 * h)
        )
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_bad_input():
    system = heat()
    v = np.zeros(4)
    with pytest.raises(ValueError, match="formulation"):
        fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation="bayes")
    with pytest.raises(ValueError, match="v"):
        fit(SteadyProblem(system, M_OBS, np.zeros(3)), [1.0, 1.0], formulation="ecfm")
    with pytest.raises(ValueError, match="v"):
        fit(SteadyProblem(system, M_OBS, np.full(4, np.nan)), [1.0, 1.0], formulation="ecfm")
    with pytest.raises(ValueError, match="M_obs"):
        fit(SteadyProblem(system, M_OBS[:, :3], v), [1.0, 1.0], formulation="ecfm")
    with pytest.raises(ValueError, match="eps"):
        fit(SteadyProblem(system, M_OBS, v), [1.0], formulation="ecfm")
    plain = GalerkinSystem([LinearTerm(K), LoadTerm.linear(F)], 2)
    with pytest.raises(ValueError, match="Gamma"):
        fit(SteadyProblem(plain, M_OBS, v), [1.0, 1.0], formulation="ecfm")


@pytest.mark.parametrize("objective", [standard_objective, ecfm_objective])
def test_public_objectives_reject_bad_data_instead_of_returning_nan(objective):
    system = heat()
    eps = [1.0, 1.0]
    with pytest.raises(ValueError, match="`v`"):
        objective(system, M_OBS, np.full(4, np.nan), eps)
    with pytest.raises(ValueError, match="`v`"):
        objective(system, M_OBS, 0.5, eps)  # a scalar must not broadcast over sensors
    with pytest.raises(ValueError, match="M_obs"):
        objective(system, M_OBS[:, :3], np.zeros(4), eps)


def test_an_optimizer_stopped_early_is_not_success():
    system = heat()
    v = M_OBS @ solve_steady(system, [3.0, -2.0]).Theta[:, 0]
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], maxiter=1)
    assert not res.success
    assert "round-off" not in res.message
