"""One inverse API (issue 23): ``fit(problem, eps0, ...)`` for every problem kind, one
result class with status and a Verdict, one verdict rule, options checked by name."""

import re

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.inverse import (
    DynamicInverseProblem,
    FitStatus,
    InverseResult,
    ReplicatedProblem,
    SteadyProblem,
    Uncertainty,
    Verdict,
    fit,
)
from ecfm_uq.spectral import SineBasis, hat_forces, load, sensor_matrix, stiffness
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
K = stiffness(B)
F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)
TRUE = np.array([3.0, -2.0])


def heat():
    """-w'' = eps0 + eps1 x on (0, 1), sine basis, hat forces on 9 sensors."""
    return GalerkinSystem([LinearTerm(K), LoadTerm.linear(F)], 2, Gamma=hat_forces(B, SENS, 0.1))


def data(sigma=0.0, seed=0):
    system = heat()
    v = M_OBS @ solve_steady(system, TRUE).Theta[:, 0]
    return system, v + sigma * np.random.default_rng(seed).standard_normal(v.size)


def documented_extra_keys():
    """The keys of the ``extra`` table in the InverseResult docstring (first column)."""
    doc = InverseResult.__doc__
    table = doc[doc.index("extra : Details") :].split("=====")
    rows = "".join(table[2:-1])  # between the header's rule and the closing rule
    return {m for line in rows.splitlines() for m in re.findall(r"``(\w+)``", line[:38])}


def check_extra_documented(res):
    assert set(res.extra) <= documented_extra_keys(), set(res.extra) - documented_extra_keys()


@pytest.mark.parametrize("formulation", ["standard", "ecfm-random"])
def test_steady_fit_reports_status_counts_uncertainty_and_verdict(formulation):
    system, v = data(0.01)
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation=formulation, sigma=0.01)
    assert isinstance(res, InverseResult)
    assert res.success and res.status is FitStatus.CONVERGED, res.message
    assert res.nfev >= res.nit >= 1
    assert isinstance(res.uncertainty, Uncertainty) and res.uncertainty.success
    assert res.uncertainty.cov.shape == (2, 2) and not hasattr(res, "eps_cov")  # v0.2 name gone
    assert isinstance(res.verdict, Verdict) and "verdict" not in res.extra
    check_extra_documented(res)
    if formulation == "standard":
        assert res.state.shape == (system.N, 1) and res.forces is None
    else:  # with sigma the random-force ECFM: posterior-mean forces, no state
        assert res.state is None and res.forces.shape == SENS.shape
    # the random-force ECFM is a marginal likelihood: its verdict is the
    # likelihood-ratio test of tau = 0 (issue 20 item 3); the standard fit's the chi2 test
    test = "chi2" if formulation == "standard" else "likelihood-ratio tau=0"
    assert res.verdict.alpha == 0.05 and res.verdict.test == test


def test_chi2_verdict_is_the_chi2_test_at_the_stated_size():
    """p-value of ||e||^2 / sigma^2 on C - n_eps degrees of freedom, consistent iff p >=
    alpha: a smaller alpha accepts what a larger one rejects."""
    system, v = data()
    v = v + 0.013 * np.array([1, -1, 1, -1, 1, -1, 1, -1, 1.0])  # a zig-zag the model can't fit
    problem = SteadyProblem(system, M_OBS, v)
    res = fit(problem, [1.0, 1.0], sigma=0.01)
    e = v - M_OBS @ solve_steady(system, res.eps).Theta[:, 0]
    p = stats.chi2.sf(e @ e / 0.01**2, v.size - 2)
    assert res.verdict.p_value == pytest.approx(p, rel=1e-9)
    assert res.verdict.details["dof"] == v.size - 2
    for alpha in (p / 2, 2 * p):
        r = fit(problem, [1.0, 1.0], sigma=0.01, alpha=alpha)
        assert r.verdict.consistent == (p >= alpha)
        assert r.verdict.alpha == alpha


def test_noise_free_data_use_the_force_to_data_rule_without_a_size():
    system, v = data()
    res = fit(SteadyProblem(system, M_OBS, v), [1.0, 1.0], formulation="ecfm")
    assert res.verdict.consistent and res.verdict.p_value is None and res.verdict.alpha is None
    assert res.verdict.details["force_to_data"] < 1e-8
    assert res.state.shape == (system.N, 1) and res.forces.shape == SENS.shape  # exact ECFM


def test_one_call_shape_for_dynamic_and_replicated_problems():
    from ecfm_uq.problems.beam import BeamModel
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=12, n_steps=15, T=0.6)
    V = m.true_data([1.75, 1.0])
    dyn = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V)
    res = fit(dyn, [1.6, 0.8], formulation="ecfm", maxiter=200)
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, [1.75, 1.0], atol=1e-6)
    assert res.verdict.consistent and res.verdict.test.startswith("force-to-data")
    assert res.forces.shape == (m.n_steps + 1, m.M_obs.shape[0]) and res.state is None
    check_extra_documented(res)
    adam = fit(dyn, [1.6, 0.8], method="adam", maxiter=3, options={"lr": 1e-2})
    assert adam.method == "adam" and adam.nit == 3
    check_extra_documented(adam)

    beam = BeamModel()
    v = beam.sample_data(1.0, 25, rng=np.random.default_rng(0))
    rep = ReplicatedProblem(beam.system, beam.M_obs, v)
    res = fit(rep, [0.5], formulation="standard", bounds=[(0.0, 2.0)])
    assert res.success and res.verdict.alpha == 0.05
    assert res.verdict.test == "moments z (Bonferroni)" and 0 <= res.verdict.p_value <= 1
    np.testing.assert_array_equal(res.forces, 0.0)  # the standard pseudo-likelihood: lam = 0
    check_extra_documented(res)


def test_dynamic_verdict_flags_data_the_model_cannot_explain():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=12, n_steps=15, T=0.6)
    V = m.true_data([1.75, 1.0])
    noise = 1e-3 * np.random.default_rng(1).standard_normal(V.shape)
    consistent = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V + noise)
    res = fit(consistent, [1.7, 0.9], sigma=1e-3)
    assert res.verdict.consistent, res.verdict.message
    shifted = V + noise + 0.05 * np.sin(np.arange(V.shape[0]))[:, None]
    wrong = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, shifted)
    res = fit(wrong, [1.7, 0.9], sigma=1e-3)
    assert not res.verdict.consistent and res.verdict.p_value < 1e-6


def test_unknown_options_and_bad_arguments_are_named():
    system, v = data(0.01)
    problem = SteadyProblem(system, M_OBS, v)
    with pytest.raises(TypeError, match="unknown name.*'lr'.*known"):
        fit(problem, [1.0, 1.0], formulation="noisy-ecfm", sigma=0.01, options={"lr": 0.1})
    with pytest.raises(ValueError, match="alpha"):
        fit(problem, [1.0, 1.0], alpha=1.5)
    with pytest.raises(ValueError, match="tol"):
        fit(problem, [1.0, 1.0], tol=0.0)
    with pytest.raises(ValueError, match="maxiter"):
        fit(problem, [1.0, 1.0], maxiter=0)
    with pytest.raises(ValueError, match="sigma"):
        fit(problem, [1.0, 1.0], sigma=-1.0)
    with pytest.raises(ValueError, match="formulation"):
        fit(problem, [1.0, 1.0], formulation="penalty")
    with pytest.raises(ValueError, match="noisy-ecfm.*sigma"):
        fit(problem, [1.0, 1.0], formulation="noisy-ecfm")
    with pytest.raises(TypeError, match="SteadyProblem"):
        fit((system, M_OBS, v), [1.0, 1.0])
    with pytest.raises(ValueError, match="bounds"):
        fit(problem, [1.0, 1.0], bounds=[(0, 1)])
    with pytest.raises(TypeError, match="options"):
        fit(problem, [1.0, 1.0], options=[("lr", 1)])


def test_every_problem_is_one_interface_and_copies_with_other_data():
    """ModelProblem, SteadyProblem, DynamicInverseProblem and ReplicatedProblem share one
    interface: n_data, with_data (a refit equals a fit of a problem built anew from the
    same data; the original keeps its data), log_likelihood."""
    from ecfm_uq.inverse import ModelProblem
    from ecfm_uq.inverse.problems.interface import InverseProblem
    from ecfm_uq.problems.beam import BeamModel
    from ecfm_uq.problems.burgers import BurgersModel

    system, v = data(0.01, seed=1)
    _, w = data(0.01, seed=2)
    steady = SteadyProblem(system, M_OBS, v)
    x = np.linspace(0, 1, 7)
    model = ModelProblem(lambda e: e[0] * np.exp(-e[1] * x), 2.0 * np.exp(-0.5 * x))
    m = BurgersModel(n_modes=8, n_steps=6, T=0.3)
    V = m.true_data([1.75, 1.0])
    dyn = DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V)
    beam = BeamModel()
    rep = ReplicatedProblem(beam.system, beam.M_obs, beam.sample_data(1.0, 5, rng=None))
    for problem, n in ((steady, 9), (model, 7), (dyn, 6 * m.M_obs.shape[0]), (rep, rep.v.size)):
        assert isinstance(problem, InverseProblem) and problem.n_data == n
        assert callable(problem.log_likelihood)
        with pytest.raises(ValueError, match="shape"):
            problem.with_data(np.zeros(problem.data.size + 1))
    refit = fit(steady.with_data(w), [1.0, 1.0], sigma=0.01)
    anew = fit(SteadyProblem(system, M_OBS, w), [1.0, 1.0], sigma=0.01)
    np.testing.assert_array_equal(refit.eps, anew.eps)
    np.testing.assert_array_equal(steady.v, v)  # the original keeps its data
    shifted = model.with_data(3.0 * np.exp(-0.5 * x))
    np.testing.assert_allclose(fit(shifted, [1.0, 1.0]).eps, [3.0, 0.5], rtol=1e-6)
    other = dyn.with_data(m.true_data([1.6, 0.9]))
    assert other._last is not dyn._last  # a copy starts cold
    np.testing.assert_allclose(fit(other, [1.7, 1.0]).eps, [1.6, 0.9], rtol=1e-5)


@pytest.mark.parametrize(
    "kw",
    [
        {},  # least squares
        {"method": "BFGS"},
        {"method": "L-BFGS-B"},
        {"method": "all-at-once"},
        {"formulation": "noisy-ecfm", "sigma": 0.01},
        {"formulation": "ecfm-random", "sigma": 0.01},
        {"formulation": "ecfm"},
    ],
)
def test_an_unknown_option_is_refused_before_the_model_is_called(kw):
    """On every path of a steady fit: the error names the key, and no load is evaluated."""
    calls = []
    F0 = load(B, np.ones_like)
    F1 = load(B, lambda x: x)

    def F(eps, t):
        calls.append(1)
        return eps[0] * F0 + eps[1] * F1

    system = GalerkinSystem(
        [LinearTerm(K), LoadTerm(F, lambda eps, t: np.column_stack([F0, F1]))],
        2, Gamma=hat_forces(B, SENS, 0.1),
    )  # fmt: skip
    problem = SteadyProblem(system, M_OBS, np.ones(SENS.size))
    with pytest.raises(TypeError, match="no_such_option"):
        fit(problem, [1.0, 1.0], options={"no_such_option": 1}, **kw)
    assert calls == []


def test_an_unknown_option_of_a_dynamic_fit_is_refused_before_any_march():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=8, n_steps=6, T=0.3)
    dyn = DynamicInverseProblem(
        m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, m.true_data([1.75, 1.0])
    )
    marched = []
    dyn.solve = lambda *a, **k: marched.append(1)  # any march would be counted
    for method in ("auto", "BFGS", "adam"):
        with pytest.raises(TypeError, match="no_such_option"):
            fit(dyn, [1.7, 1.0], method=method, options={"no_such_option": 1})
    assert marched == []


def test_every_formulation_fills_the_typed_fields_and_documents_its_extra_keys():
    """state, forces and the extra table of the InverseResult docstring: the all-at-once
    SLSQP fits, the random-force ECFM and a model function."""
    from ecfm_uq.inverse import ModelProblem, profile_likelihood

    system, v = data(0.01)
    problem = SteadyProblem(system, M_OBS, v)
    noisy = fit(problem, [1.0, 1.0], formulation="noisy-ecfm", sigma=0.01)
    assert noisy.state.shape == (system.N,) and noisy.forces.shape == SENS.shape
    assert noisy.nfev > 0 and "nfev" not in noisy.extra
    std = fit(problem, [1.0, 1.0], method="all-at-once")
    assert std.state.shape == (system.N,) and std.forces is None
    random = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=0.01)
    assert random.state is None and random.forces.shape == SENS.shape
    assert random.extra["force_stderr"].shape == SENS.shape
    model = fit(ModelProblem(lambda e: M_OBS @ solve_steady(system, e).Theta[:, 0], v),
                [1.0, 1.0], sigma=0.01)  # fmt: skip
    assert model.state is None and model.forces is None
    before = dict(model.extra)
    profile_likelihood(model, which=[0])
    assert model.extra.keys() == before.keys()  # a profile is computed from a result, not stored
    for res in (noisy, std, random, model):
        check_extra_documented(res)
    assert "prediction" in model.extra


def test_fit_status_prints_its_name():
    """``print(res.status)`` says what happened (issue 37), the code stays an int."""
    from ecfm_uq.inverse import FitStatus

    assert str(FitStatus.CONVERGED) == "CONVERGED"
    assert f"{FitStatus.STALLED:>8}" == " STALLED"
    assert FitStatus.MAX_ITERATIONS == 1 and int(FitStatus.STALLED) == 2
