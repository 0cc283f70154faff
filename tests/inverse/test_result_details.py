"""``result.extra`` is one typed record per formulation (issue 37: "typed details"), each
field documented, read like the dict it replaced; a whitened ``sigma`` is named as given
where a message is written; ``interval_likelihood`` is a field only.

Every row of ``FITTERS`` is fitted once on a small problem and its ``extra`` checked
against its record's type and docstring; the records' fields against the key table of
the InverseResult docstring."""

import dataclasses
import re

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.inverse import (
    DynamicInverseProblem,
    InverseResult,
    ModelProblem,
    ReplicatedProblem,
    SteadyProblem,
    fit,
    profile_likelihood,
)
from ecfm_uq.inverse.core import details as details_module
from ecfm_uq.inverse.core.details import (
    AllAtOnceDetails,
    Details,
    DynamicDetails,
    InnerOuterDetails,
    ModelDetails,
    OdeDetails,
    OdeEcfmDetails,
    OdeRandomDetails,
    PenaltyDetails,
    RandomForceDetails,
    ReplicatedDetails,
)
from ecfm_uq.inverse.fitting import FITTERS
from ecfm_uq.inverse.formulations.random_forces import RandomForceModel
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.spectral import SineBasis, hat_forces, load, sensor_matrix, stiffness
from ecfm_uq.studies.ode import TRUTH as LV_TRUTH
from ecfm_uq.studies.ode import lv_problem, simulate
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)
HEAT = GalerkinSystem(
    [LinearTerm(stiffness(B)),
     LoadTerm.linear(np.column_stack([load(B, np.ones_like), load(B, lambda x: x)]))],
    2, Gamma=hat_forces(B, SENS, 0.1),
)  # fmt: skip
HEAT_TRUE = np.array([3.0, -2.0])
SIGMA = 0.01


def _steady_data(sigma=SIGMA, seed=0):
    v = M_OBS @ solve_steady(HEAT, HEAT_TRUE).Theta[:, 0]
    return v + sigma * np.random.default_rng(seed).standard_normal(v.size)


def _replicated():
    """(K0 - omega K1 - eps KG) theta = F + Gamma lam, omega ~ U(0, 1), 25 draws."""
    K0 = np.array([[6.0, -1, 0], [-1, 6, -1], [0, -1, 5]])
    K1 = 1.5 * np.array([[1.0, 0.2, 0], [0.2, 1.5, 0.1], [0, 0.1, 0.8]])
    KG = np.array([[1.0, 0.3, 0], [0.3, 1, 0.2], [0, 0.2, 1]])
    gamma = np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.3], [0.0, 0.2, 1.0]])
    m_obs = np.array([[1.0, 0.5, 0.2], [0.3, 1.0, 0.4], [0.1, 0.2, 1.0]])
    basis = ChaosBasis(3)
    system = GalerkinSystem(
        [LinearTerm(K0), LinearTerm(-K1, G=weighted_gram(basis, lambda w: w)),
         LinearTerm(KG, coef=Coefficient.parameter(0, scale=-1.0)),
         LoadTerm.constant(np.array([1.0, 2.0, 1.5]))],
        1, basis=basis, Gamma=gamma,
    )  # fmt: skip
    Theta = solve_steady(system, [1.0], strict=True).Theta
    omega = np.random.default_rng(0).random(25)
    return ReplicatedProblem(system, m_obs, m_obs @ Theta @ basis.evaluate(omega).T)


def _dynamic():
    m = BurgersModel(n_modes=8, n_steps=10, T=0.6)
    V = m.true_data([1.75, 1.0])
    V = V + 1e-3 * np.random.default_rng(0).standard_normal(V.shape)
    return DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V)


def _ode():
    times = np.arange(0.0, 9.0)
    data = simulate(times) * (1 + 0.02 * np.random.default_rng(3).standard_normal((9, 2)))
    return lv_problem(times, data, rtol=1e-7), 0.02 * np.abs(data)


def _model():
    x = np.linspace(0.0, 1.0, 12)
    y = 1.0 + 2.0 * x + 0.01 * np.random.default_rng(0).standard_normal(x.size)
    return ModelProblem(lambda e: e[0] + e[1] * x, y)


def _steady_case():
    """The heat rod's steady problem, its start and sigma: one case of every steady row."""
    return SteadyProblem(HEAT, M_OBS, _steady_data()), [1.0, 1.0], {"sigma": SIGMA}


#: one small fit of each FITTERS row: (problem, eps0, keywords) -> its record's type
CASES = {
    ("model", "standard"): (lambda: (_model(), [0.5, 0.5], {"sigma": 0.01}), ModelDetails),
    ("ode", "standard"): (lambda: (_ode()[0], np.array(LV_TRUTH) * 1.02, {}), OdeDetails),
    ("ode", "ecfm"): (
        lambda: (_ode()[0], np.array(LV_TRUTH) * 1.02, {"sigma": 0.5}),
        OdeEcfmDetails,
    ),
    ("ode", "ecfm-random"): (
        lambda: (_ode()[0], np.array(LV_TRUTH) * 1.02, {"sigma": _ode()[1]}),
        OdeRandomDetails,
    ),
    ("steady", "standard"): (_steady_case, Details),
    ("steady", "ecfm"): (_steady_case, Details),
    ("steady", "ecfm-random"): (_steady_case, RandomForceDetails),
    ("steady", "noisy-ecfm"): (_steady_case, AllAtOnceDetails),
    ("dynamic", "standard"): (lambda: (_dynamic(), [1.6, 0.8], {"sigma": 1e-3}), DynamicDetails),
    ("dynamic", "ecfm"): (lambda: (_dynamic(), [1.6, 0.8], {"sigma": 1e-3}), DynamicDetails),
    ("replicated", "standard"): (
        lambda: (_replicated(), [0.5], {"bounds": [(0.0, 1.4)]}),
        ReplicatedDetails,
    ),
    ("replicated", "inner-outer"): (
        lambda: (_replicated(), [0.5], {"bounds": [(0.0, 1.4)]}),
        InnerOuterDetails,
    ),
    ("replicated", "ecfm"): (
        lambda: (_replicated(), [0.5], {"bounds": [(0.0, 1.4)]}),
        InnerOuterDetails,
    ),
    ("replicated", "penalty"): (
        lambda: (_replicated(), [0.5], {"bounds": [(0.0, 1.4)]}),
        PenaltyDetails,
    ),
}

#: the keys each record must hold after a successful fit of its row (not only "some")
PRESENT = {
    ModelDetails: {"prediction"},
    OdeDetails: {"prediction", "n_missing"},
    OdeEcfmDetails: {"n_missing", "significant_forces", "force_cov"},
    OdeRandomDetails: {"tau", "standard", "n_missing"},
    RandomForceDetails: {
        "force_stderr",
        "tau",
        "force_prior",
        "force_tau",
        "standard",
        "n_solves",
    },  # fmt: skip
    AllAtOnceDetails: {"discrepancy", "z", "moment_bounds", "inequality", "slsqp_status"},
    DynamicDetails: set(),
    Details: set(),
    ReplicatedDetails: {"force_norm", "neg_log_likelihood", "mu", "var", "n_solves"},
    InnerOuterDetails: {"force_norm", "inner_nit", "hess_lam_min_eig", "dlam_deps"},
    PenaltyDetails: {"force_norm", "penalty", "log_force_term", "force_scaling_slope"},
}

RECORDS = [getattr(details_module, name) for name in details_module.__all__]


def _documented_fields(cls):
    """The names in the Attributes sections ("a, b : type") of a record's docstring and
    of the records it extends."""
    names = set()
    for base in cls.__mro__:
        doc = base.__dict__.get("__doc__") or ""
        if not issubclass(base, Details) or "Attributes" not in doc:
            continue
        for line in doc[doc.index("Attributes") :].splitlines():
            m = re.match(r"^    (\w+(?:, \w+)*) :", line)
            if m:
                names.update(m.group(1).split(", "))
    return names


def _result_table_keys():
    doc = InverseResult.__doc__
    rows = "".join(doc[doc.index("extra : Details") :].split("=====")[2:-1])
    return {m for line in rows.splitlines() for m in re.findall(r"``(\w+)``", line[:38])}


def test_every_row_of_the_table_has_a_case():
    assert set(CASES) == set(FITTERS)


@pytest.mark.parametrize("row", list(CASES), ids=lambda r: "-".join(r))
def test_every_formulations_extra_is_its_record_with_documented_fields_only(row):
    make, record = CASES[row]
    problem, eps0, kw = make()
    res = fit(problem, eps0, formulation=row[1], **kw)
    # the penalty form goes down its lam -> 0 valley on these data, and says so
    # (test_likelihood.py): what it reports is still its record
    assert res.success or row == ("replicated", "penalty"), res.message
    assert type(res.extra) is record, type(res.extra)
    assert set(res.extra) <= set(record.documented()) <= _documented_fields(record)
    assert PRESENT[record] <= set(res.extra), PRESENT[record] - set(res.extra)
    # the mapping and the attributes are one: each key's value is its field's
    for key, value in res.extra.items():
        assert value is getattr(res.extra, key) and value is not None
    assert "interval_likelihood" not in res.extra  # a field of the result, one place


def test_every_records_fields_are_documented_on_it_and_in_the_results_table():
    fields = set()
    for cls in RECORDS:
        assert set(cls.documented()) == _documented_fields(cls), cls.__name__
        fields |= set(cls.documented())
    assert fields == _result_table_keys()
    # no key of the old dict said what another says: the number of stacked unknowns is z.size
    assert "n_variables" not in fields and "interval_likelihood" not in fields


def test_a_record_reads_like_the_dict_it_replaced_and_takes_no_other_key():
    d = PenaltyDetails(force_norm=1.5, penalty=100.0, mu=np.zeros(3))
    assert list(d) == ["force_norm", "mu", "penalty"] and len(d) == 3
    assert d["penalty"] == 100.0 == d.penalty and d.get("grad_lam_norm") is None
    assert "penalty" in d and "grad_lam_norm" not in d and "nope" not in d
    assert dict(d).keys() == {"force_norm", "mu", "penalty"}
    assert Details() == {} and len(Details()) == 0
    with pytest.raises(KeyError, match="not computed by this fit"):
        d["grad_lam_norm"]
    with pytest.raises(KeyError, match="not a detail.*penalty"):
        d["nope"]
    with pytest.raises(TypeError, match="nope"):
        PenaltyDetails(nope=1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.penalty = 1.0
    with pytest.raises(TypeError, match="`extra` must be a Details"):
        InverseResult(eps=[1.0], loss=0.0, extra={"tau": 1.0})


def test_adams_gradients_are_dynamic_details():
    res = fit(_dynamic(), [1.6, 0.8], method="adam", maxiter=3, options={"lr": 1e-2})
    assert type(res.extra) is DynamicDetails
    assert set(res.extra) == {"grad", "grad_history"}
    assert res.extra["grad_history"].shape == (4, 2)
    np.testing.assert_array_equal(res.extra["grad"], res.extra["grad_history"][-1])


def test_messages_name_a_whitened_sigma_as_given_and_a_number_as_itself():
    v = _steady_data(seed=1)
    sigma = np.full(SENS.size, SIGMA) * np.linspace(1.0, 3.0, SENS.size)
    problem = SteadyProblem(HEAT, M_OBS, v)
    arr = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=sigma)
    one = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=SIGMA)
    given = "sigma=1 (whitened: sigma per observation (0.01 to 0.03))"
    assert given in arr.likelihood.description
    assert given in arr.interval_likelihood.description
    assert f"sigma={SIGMA:g}" in one.likelihood.description and "whitened" not in str(
        [one.likelihood.description, one.interval_likelihood.description]
    )
    # the all-at-once verdict: the moment test of the whitened discrepancy
    slsqp = fit(problem, [1.0, 1.0], sigma=sigma, method="all-at-once")
    assert f"against {given}" in slsqp.verdict.message
    plain = fit(problem, [1.0, 1.0], sigma=SIGMA, method="all-at-once")
    assert f"against sigma = {SIGMA:g}," in plain.verdict.message


def test_why_tau_cannot_be_profiled_is_the_interval_likelihood_and_intervals_hold_it(
    monkeypatch,
):
    problem = SteadyProblem(HEAT, M_OBS, _steady_data(seed=2))
    held = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=SIGMA,
               options={"tau_in_intervals": "held"})  # fmt: skip

    def fails(self):
        raise ConvergenceError("no REML root here")

    monkeypatch.setattr(RandomForceModel, "profiled_likelihood", fails)
    res = fit(problem, [1.0, 1.0], formulation="ecfm-random", sigma=SIGMA)
    assert isinstance(res.interval_likelihood, str)
    assert "no REML root here" in res.interval_likelihood
    assert "interval_likelihood" not in res.extra
    assert held.interval_likelihood is None
    np.testing.assert_array_equal(res.eps, held.eps)
    ours = profile_likelihood(res, which=[0]).intervals
    theirs = profile_likelihood(held, which=[0]).intervals
    np.testing.assert_array_equal(ours, theirs)
