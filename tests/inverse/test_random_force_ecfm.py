"""ECFM with noisy data (issue 20 items 3-4): the constraint forces as a random
discrepancy with a (restricted) marginal likelihood, its test of tau = 0, and the force
map of a localized source missing from a model with a parameter inside the operator."""

import numpy as np
import pytest

from ecfm_uq.inverse import ModelProblem, SteadyProblem, fit
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)
TRUE = np.array([1.5, 20.0])
SOURCE_AT = 0.62


def terms():
    """-w'' + 10**eps0 w = eps1: a reaction rate inside the operator."""
    return [
        LinearTerm(stiffness(B)),
        LinearTerm(mass(B), Coefficient.power10(0, sign=1.0)),
        LoadTerm.scaled(-load(B, np.ones_like), Coefficient.parameter(1)),
    ]


def model():
    return GalerkinSystem(terms(), 2, Gamma=hat_forces(B, SENS, 0.05))


def readings(amplitude, rel_noise, seed):
    """Data from the truth plus a narrow source at SOURCE_AT the model does not have."""
    bump = load(B, lambda x: np.exp(-0.5 * ((x - SOURCE_AT) / 0.02) ** 2))
    truth = GalerkinSystem([*terms(), LoadTerm.scaled(-bump, Coefficient.parameter(2))], 3)
    v = M_OBS @ solve_steady(truth, [*TRUE, amplitude]).Theta[:, 0]
    sigma = rel_noise * np.abs(v).mean()
    return v + sigma * np.random.default_rng(seed).standard_normal(v.size), sigma


def test_on_consistent_data_it_is_the_standard_estimate():
    v, sigma = readings(0.0, 0.02, 0)
    res = fit(SteadyProblem(model(), M_OBS, v), [1.0, 10.0], formulation="ecfm-random", sigma=sigma)
    std = res.extra["standard"]
    assert res.success and res.extra["tau"] == 0.0
    np.testing.assert_array_equal(res.eps, std.eps)
    np.testing.assert_array_equal(res.uncertainty.stderr, std.uncertainty.stderr)
    assert res.verdict.consistent and res.verdict.p_value == 1.0
    assert res.verdict.test == "likelihood-ratio tau=0" and res.verdict.alpha == 0.05
    np.testing.assert_array_equal(res.forces, 0.0)


@pytest.mark.parametrize("amplitude", [10.0, 60.0])
def test_a_missing_source_is_flagged_and_mapped_and_the_estimate_is_not_worse(amplitude):
    v, sigma = readings(amplitude, 1e-3, 1)
    res = fit(SteadyProblem(model(), M_OBS, v), [1.0, 10.0], formulation="ecfm-random", sigma=sigma)
    std = res.extra["standard"]
    assert res.success, res.message
    assert not res.verdict.consistent and res.verdict.p_value < 1e-3  # MC resolution 1/4001
    lam = np.abs(res.forces)
    assert np.argmax(lam) == np.argmin(np.abs(SENS - SOURCE_AT))  # the sensor nearest it
    assert lam.max() > 4 * np.median(lam)
    # the discrepancy absorbs the source instead of the reaction rate absorbing it
    assert np.all(np.abs(res.eps - TRUE) <= np.abs(std.eps - TRUE))
    z = res.verdict.details["force_z"]
    assert abs(z[np.argmax(lam)]) > 3


def test_formulations_are_chosen_by_name_and_bad_options_are_named():
    v, sigma = readings(0.0, 0.02, 2)
    problem = SteadyProblem(model(), M_OBS, v)
    # sigma does not switch the estimator: "ecfm" is the paper's exact-match ECFM with it
    exact = fit(problem, [1.0, 10.0], formulation="ecfm", sigma=sigma)
    plain = fit(problem, [1.0, 10.0], formulation="ecfm")
    np.testing.assert_array_equal(exact.eps, plain.eps)
    assert exact.verdict.test == "chi2" and "tau" not in exact.extra
    random = fit(problem, [1.0, 10.0], formulation="ecfm-random", sigma=sigma)
    assert "tau" in random.extra
    with pytest.raises(ValueError, match=r"options\['forces'\]` is gone.*'ecfm-random'"):
        fit(problem, [1.0, 10.0], formulation="ecfm", sigma=sigma, options={"forces": "exact"})
    with pytest.raises(ValueError, match="needs `sigma`"):
        fit(problem, [1.0, 10.0], formulation="ecfm-random")
    with pytest.raises(ValueError, match="for a model problem.*'standard'"):
        fit(ModelProblem(lambda e: e, [1.0]), [1.0], formulation="ecfm-random", sigma=1.0)
    with pytest.raises(TypeError, match="unknown name"):
        fit(problem, [1.0, 10.0], formulation="ecfm-random", sigma=sigma, options={"lr": 1})


@pytest.mark.slow
@pytest.mark.parametrize("prior", ["shared", "sparse"])
@pytest.mark.parametrize("scale", [1e9, 1e-9])
def test_equations_in_other_units_give_the_same_fits_intervals_and_force_map(scale, prior):
    """The same rod with every equation multiplied by `scale` (physical units, e.g. Pa):
    standard and random-force estimates, profile intervals, the verdict and the force
    z-scores do not change (Gamma is in the same units, so the forces do not either)."""
    from ecfm_uq.inverse import profile_intervals

    def scaled():
        t = terms()
        return GalerkinSystem(
            [LinearTerm(scale * t[0].K), LinearTerm(scale * t[1].K, t[1].coef),
             LoadTerm.scaled(-scale * load(B, np.ones_like), Coefficient.parameter(1))],
            2, Gamma=scale * hat_forces(B, SENS, 0.05),
        )  # fmt: skip

    for amplitude, noise in ((0.0, 0.02), (10.0, 1e-3)):
        v, sigma = readings(amplitude, noise, 4)
        ref, res = (
            fit(SteadyProblem(m, M_OBS, v), [1.0, 10.0], formulation="ecfm-random", sigma=sigma,
                options={"force_prior": prior})
            for m in (model(), scaled())
        )  # fmt: skip
        assert res.success and res.verdict.consistent == ref.verdict.consistent
        # estimates and interval ends agree to a small fraction of the interval's width
        # (the eps search stops at its own tolerance, not at round-off)
        ci, ci_ref = profile_intervals(res), profile_intervals(ref)
        width = ci_ref[:, 1] - ci_ref[:, 0]
        assert np.all(np.abs(res.eps - ref.eps) <= 2e-3 * width)
        assert np.all(np.abs(ci - ci_ref) <= 2e-3 * width[:, None])
        # the force map to the same accuracy, relative to its largest entry
        for key, a, b in (("lam", res.forces, ref.forces),
                          ("z", res.verdict.details["force_z"], ref.verdict.details["force_z"])):  # fmt: skip
            assert np.max(np.abs(a - b)) <= 1e-3 * max(np.max(np.abs(b)), 1e-12), key
