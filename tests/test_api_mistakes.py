"""Catalogue of realistic API mistakes (issue 15; documented in docs/mistakes.md).

Each entry makes one mistake and asserts the exception type AND the words of the message
(which argument, what was expected, the fix). A hypothesis test feeds malformed shapes and
values to the public constructors: only ValueError/TypeError or the package's own
exceptions may come out.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecfm_uq.chaos import ChaosBasis, expectation_tensor, weighted_gram
from ecfm_uq.chaos.quadrature import tensor_gauss_legendre
from ecfm_uq.errors import ConvergenceError, MemoryBudgetError, ModelEvaluationError
from ecfm_uq.inverse import SteadyProblem, fit
from ecfm_uq.inverse.statistics.verdict import consistency_verdict
from ecfm_uq.memory import set_memory_budget
from ecfm_uq.spectral import (
    SineBasis,
    TensorBasis2D,
    gaussian_forces,
    hat_forces,
    rbf_forces,
    sensor_matrix,
    stiffness,
)
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    QuadraticTerm,
    SolverOptions,
    march,
    solve_steady,
)

N = 3
K = np.diag([2.0, 3.0, 4.0])
F = np.ones(N)
B1 = SineBasis(4)


def _system(*extra, n_eps=1, coef=None, **kw):
    coef = Coefficient.power10(0) if coef is None else coef
    return GalerkinSystem([LinearTerm(K, coef), *extra], n_eps=n_eps, **kw)


def _ok_system(**kw):
    return _system(LoadTerm.constant(F), **kw)


# (id, callable, exception type, words that must appear in the message)
MISTAKES = [
    # -- terms -------------------------------------------------------------------------
    ("K not square", lambda: LinearTerm(np.ones((3, 2))), ValueError, "`K` must be square"),
    ("K a string", lambda: LinearTerm("K"), TypeError, "got str 'K'"),
    ("K 1-D", lambda: LinearTerm(np.ones(3)), ValueError, "`K` must be 2-D"),
    ("K with NaN", lambda: LinearTerm(np.full((2, 2), np.nan)), ValueError, "NaN or inf"),
    ("coef a string", lambda: LinearTerm(K, "1e-2"), TypeError, "Coefficient(value, grad)"),
    ("coef a lambda", lambda: LinearTerm(K, lambda e: e[0]), TypeError, "`coef` must be"),
    ("G wrong P", lambda: _system(G=None) and None, None, None),  # placeholder, replaced
    ("A not cubic", lambda: QuadraticTerm(np.ones((3, 3, 2))), ValueError, "(N, N, N)"),
    ("load a string", lambda: LoadTerm.constant("abc"), TypeError, "got str 'abc'"),
    ("load 2-D", lambda: LoadTerm.constant(np.ones((3, 1))), ValueError, "`F` must be 1-D"),
    ("load array to LoadTerm", lambda: LoadTerm(F), TypeError, "LoadTerm.constant"),
    ("dF not callable", lambda: LoadTerm(lambda e, t: F, dF=F), TypeError, "`dF` must"),
    ("scaled load with NaN", lambda: LoadTerm.scaled([1.0, np.nan], 1.0), ValueError, "NaN"),
    # -- coefficients ------------------------------------------------------------------
    ("index negative", lambda: Coefficient.parameter(-1), ValueError, "`index` must be >= 0"),
    ("index a float", lambda: Coefficient.power10(0.5), TypeError, "`index` must be an int"),
    ("scale a string", lambda: Coefficient.parameter(0, scale="2"), TypeError, "`scale`"),
    ("constant inf", lambda: Coefficient.constant(np.inf), ValueError, "`c` must be finite"),
    ("value not callable", lambda: Coefficient(1.0, None), TypeError, "`value` must be"),
    # -- system ------------------------------------------------------------------------
    (
        "coefficient index beyond n_eps",
        lambda: _system(LoadTerm.constant(F), coef=Coefficient.power10(2), n_eps=1),
        ValueError,
        "uses parameter index 2 but the system has n_eps=1",
    ),
    (
        "load of the wrong size",
        lambda: _system(LoadTerm.constant(np.ones(4), name="source")),
        ValueError,
        "load term 'source': the load has 4 entries but the system's state has N=3",
    ),
    (
        "linear load B with wrong n_eps",
        lambda: _system(LoadTerm.linear(np.ones((N, 3))), n_eps=1),
        ValueError,
        "`B` has 3 columns but the system has n_eps=1",
    ),
    (
        "terms of different N",
        lambda: GalerkinSystem([LinearTerm(K, name="a"), LinearTerm(np.eye(2), name="b")], 0),
        ValueError,
        "terms disagree on the state size N ('a': 3, 'b': 2)",
    ),
    ("no terms", lambda: GalerkinSystem([], 1), ValueError, "at least one term"),
    (
        "only loads",
        lambda: GalerkinSystem([LoadTerm.constant(F)], 0),
        ValueError,
        "the state size N is unknown",
    ),
    ("a matrix as a term", lambda: GalerkinSystem([K], 0), TypeError, "unsupported ndarray"),
    ("n_eps a float", lambda: _ok_system(n_eps=1.0), TypeError, "`n_eps` must be an integer"),
    ("Gamma wrong rows", lambda: _ok_system(Gamma=np.ones((4, 2))), ValueError, "3 rows (N)"),
    ("M wrong shape", lambda: _ok_system(M=np.eye(2)), ValueError, "`M` must have shape"),
    ("basis not a ChaosBasis", lambda: _ok_system(basis="P3"), TypeError, "ChaosBasis"),
    (
        "residual of a flat state",
        lambda: _ok_system().residual(np.zeros(N), [0.0]),
        ValueError,
        "`Theta` must have shape (N, P) = (3, 1), got (3,)",
    ),
    # -- solving -----------------------------------------------------------------------
    ("eps wrong length", lambda: solve_steady(_ok_system(), [1.0, 2.0]), ValueError, "`eps`"),
    ("eps a string", lambda: solve_steady(_ok_system(), "0.5"), TypeError, "got str '0.5'"),
    ("eps NaN", lambda: solve_steady(_ok_system(), [np.nan]), ValueError, "NaN or inf"),
    ("tol negative", lambda: solve_steady(_ok_system(), [0.0], tol=-1), ValueError, "`tol`"),
    (
        "lam without Gamma",
        lambda: solve_steady(_ok_system(), [0.0], lam=[1.0]),
        ValueError,
        "no constraint forces",
    ),
    ("unknown solver", lambda: SolverOptions(solver="lu"), ValueError, "unknown `solver`"),
    ("solver a list", lambda: SolverOptions(solver=["cg"]), ValueError, "list ['cg']"),
    (
        "unknown solver option",
        lambda: solve_steady(_ok_system(), [0.0], solver={"solver": "cg", "tol": 1e-8}),
        TypeError,
        "`solver` has unknown option(s) ['tol']; known options are ['solver',",
    ),
    ("rtol zero", lambda: SolverOptions(rtol=0.0), ValueError, "`rtol` must be positive"),
    (
        "march without M",
        lambda: march(_ok_system(), [0.0], np.zeros(N), 0.1, 2),
        ValueError,
        "mass",
    ),
    (
        "callable load of the wrong size",
        lambda: solve_steady(_system(LoadTerm(lambda e, t: np.ones(5), name="src")), [0.0]),
        ValueError,
        "load term 'src': F(eps, t) returned shape (5,), expected (3,)",
    ),
    (
        "random load of the wrong chaos size",
        lambda: solve_steady(
            GalerkinSystem(
                [LinearTerm(K), LoadTerm(lambda e, t: np.ones((N, 2)), name="rand")],
                1,
                basis=ChaosBasis(2),
            ),
            [0.0],
        ),
        ValueError,
        "load term 'rand': F(eps, t) returned shape (3, 2), expected (3,) or (3, 3)",
    ),
    (
        "load derivative of the wrong shape",
        lambda: solve_steady(
            _system(LoadTerm(lambda e, t: F, lambda e, t: np.ones((N, 2)), name="src")), [0.0]
        ).eps_sensitivity(),
        ValueError,
        "load term 'src': dF(eps, t) returned shape (3, 2), expected (3, 1)",
    ),
    (
        "quadratic form without size",
        lambda: QuadraticTerm(type("Form", (), {"matrix": None})()),
        TypeError,
        "lacks ['apply', 'size']",
    ),
    # -- chaos -------------------------------------------------------------------------
    ("order negative", lambda: ChaosBasis(-1), ValueError, "`order` must be >= 0"),
    ("dim zero", lambda: ChaosBasis(2, dim=0), ValueError, "`dim` must be >= 1"),
    ("unknown index set", lambda: ChaosBasis(2, index_set="full"), ValueError, "`index_set`"),
    ("rank 4", lambda: expectation_tensor(ChaosBasis(2), 4), ValueError, "unknown `rank`"),
    (
        "weighted_gram g wrong size",
        lambda: weighted_gram(ChaosBasis(2), np.ones(2)),
        ValueError,
        "`g` as samples must have shape",
    ),
    # -- spatial bases, forces, sensors ------------------------------------------------
    ("SineBasis(0)", lambda: SineBasis(0), ValueError, "must be"),
    ("TensorBasis2D of ints", lambda: TensorBasis2D(4), TypeError, "`bx` must be a 1-D"),
    ("sensor outside", lambda: sensor_matrix(B1, [0.5, 1.5]), ValueError, "lie in [0, 1]"),
    ("no sensors", lambda: sensor_matrix(B1, []), ValueError, "`points` is empty"),
    ("sensors a string", lambda: sensor_matrix(B1, "0.5"), TypeError, "got str '0.5'"),
    (
        "hat centre outside",
        lambda: hat_forces(B1, [0.5, 1.2], 0.1),
        ValueError,
        "`centers` must lie in [0, 1] (the domain), got centre 1 at 1.2",
    ),
    (
        "gaussian centre outside",
        lambda: gaussian_forces(B1, [-0.1], 50.0),
        ValueError,
        "got centre 0 at -0.1",
    ),
    (
        "rbf centre outside",
        lambda: rbf_forces(TensorBasis2D(SineBasis(2)), [[0.5, 0.5], [0.5, 2.0]], 50.0),
        ValueError,
        "the unit square [0, 1]^2 (the domain), got centre 1",
    ),
    (
        "gaussian force far too narrow",
        lambda: gaussian_forces(B1, [0.5], 1e16),
        MemoryBudgetError,
        "pass a smaller `omega`",
    ),
    ("half_width zero", lambda: hat_forces(B1, [0.5], 0.0), ValueError, "`half_width`"),
    ("no centres", lambda: hat_forces(B1, [], 0.1), ValueError, "`centers` is empty"),
    ("forces on a list", lambda: hat_forces([1, 2], [0.5], 0.1), TypeError, "`basis` must"),
    ("rbf on 1-D basis", lambda: rbf_forces(B1, [[0.5, 0.5]], 5.0), TypeError, "TensorBasis2D"),
    # -- inverse -----------------------------------------------------------------------
    (
        "ecfm without Gamma",
        lambda: fit(SteadyProblem(_ok_system(), np.eye(N), F), [0.0], formulation="ecfm"),
        ValueError,
        "needs a system with constraint forces",
    ),
    (
        "M_obs wrong columns",
        lambda: fit(SteadyProblem(_ok_system(), np.ones((2, 4)), [1.0, 1.0]), [0.0]),
        ValueError,
        "`M_obs` must have 3 columns",
    ),
    (
        "unknown formulation",
        lambda: fit(SteadyProblem(_ok_system(), np.eye(N), F), [0.0], formulation="ols"),
        ValueError,
        "unknown `formulation`",
    ),
    (
        "random forces without sigma",
        lambda: fit(SteadyProblem(_GAMMA_SYSTEM, np.eye(N), F), [0.0], formulation="ecfm-random"),
        ValueError,
        "formulation='ecfm-random' needs `sigma`",
    ),
    (
        "sigma per sensor for the noisy ECFM",
        lambda: fit(
            SteadyProblem(_GAMMA_SYSTEM, np.eye(N), F),
            [0.0],
            formulation="noisy-ecfm",
            sigma=[0.1, 0.2, 0.3],
        ),  # fmt: skip
        ValueError,
        "formulation='noisy-ecfm' takes `sigma` as one number",
    ),
]
# the G placeholder: a coupling of the wrong chaos size
MISTAKES[6] = (
    "G of the wrong P",
    lambda: GalerkinSystem(
        [LinearTerm(K, G=np.eye(2), name="k"), LoadTerm.constant(F)], 0, basis=ChaosBasis(2)
    ),
    ValueError,
    "term 'k': `G` has shape (2, 2), expected (3, 3)",
)


def test_catalogue_is_large():
    assert len(MISTAKES) >= 40
    assert len({m[0] for m in MISTAKES}) == len(MISTAKES)


@pytest.mark.parametrize(
    ("fn", "exc", "words"), [m[1:] for m in MISTAKES], ids=[m[0] for m in MISTAKES]
)
def test_mistake(fn, exc, words):
    with pytest.raises(exc) as info:
        fn()
    assert words in str(info.value)


# -- numerical failures become reported failures ----------------------------------------


def test_overflowing_coefficient_is_a_reported_failure():
    system = _system(LoadTerm.constant(F), coef=Coefficient.power10(0, sign=1.0))
    sol = solve_steady(system, [400.0])
    assert not sol.success
    assert "10**(1*eps[0]) cannot be evaluated at eps=[400.0] (overflow)" in sol.message


def test_overflowing_coefficient_strict_raises_convergence_error():
    system = _system(LoadTerm.constant(F), coef=Coefficient.power10(0, sign=1.0))
    with pytest.raises(ConvergenceError, match="overflow"):
        solve_steady(system, [400.0], strict=True)


def test_coefficient_evaluation_names_itself():
    with pytest.raises(ModelEvaluationError, match=r"eps\[0\]\) cannot be evaluated"):
        Coefficient.power10(0).value(np.array([-1e4]))


def test_nan_from_a_callable_load_is_reported():
    system = _system(LoadTerm(lambda e, t: np.full(N, np.nan), name="src"))
    sol = solve_steady(system, [0.0])
    assert not sol.success
    assert "load term 'src': F(eps, t) returned NaN or inf" in sol.message


def _heat_system(F=None, forces=True, n=8):
    """1-D diffusion 10**eps0 K theta = F (default all ones), 3 sensors and, with
    ``forces``, hat constraint forces at them; returns ``(system, M_obs)``."""
    basis = SineBasis(n)
    x = np.array([0.25, 0.5, 0.75])
    F = np.ones(n) if F is None else F
    system = GalerkinSystem(
        [LinearTerm(stiffness(basis), Coefficient.power10(0, sign=1.0)), LoadTerm.constant(F)],
        1,
        Gamma=hat_forces(basis, x, 0.1) if forces else None,
    )
    return system, sensor_matrix(basis, x)


def test_bfgs_fit_on_unexplainable_data_says_the_coefficient_ran_away():
    """Standard BFGS on data of the wrong sign drives 10**eps up; the verdict says so: an
    identifiability finding (no noise level given, so no consistency test), and with sigma
    the chi-squared test fails too."""
    system, M = _heat_system(forces=False)
    v = -np.ones(3)  # a positive load can never give negative deflections
    res = fit(SteadyProblem(system, M, v), [0.0], maxiter=200)
    assert np.all(np.isfinite(res.eps))
    assert res.verdict.consistent is None
    assert "coefficient of term 'linear' is extreme" in res.verdict.identifiability
    assert "coefficient of term 'linear' is extreme" in res.message
    res = fit(SteadyProblem(system, M, v), [0.0], maxiter=200, sigma=0.1)
    assert res.verdict.consistent is False


def test_objective_overflow_is_a_convergence_error_not_overflow_error():
    from ecfm_uq.inverse import ecfm_objective, standard_objective

    system, M = _heat_system()
    for objective in (standard_objective, ecfm_objective):
        with pytest.raises(ConvergenceError, match="overflow"):
            objective(system, M, np.ones(3), [400.0])


def test_fit_from_an_overflowing_start_is_refused_clearly():
    system, M = _heat_system()
    with pytest.raises(ConvergenceError, match=r"cannot be solved at eps0=\[400\.\].*overflow"):
        fit(
            SteadyProblem(system, M, np.ones(3)),
            [400.0],
            formulation="ecfm",
        )


def test_fit_treats_overflow_at_trial_points_as_failed_inner_solves():
    """A bounded fit whose trial points overflow: reported, never a raw OverflowError."""
    system, M = _heat_system()
    v = M @ solve_steady(system, [0.0]).Theta[:, 0]
    calls = []
    orig = system.terms[0].coef._value

    def value(eps):  # overflow on the first trial point after eps0 (as a huge step would)
        calls.append(float(eps[0]))
        if len(calls) > 1 and abs(float(eps[0]) - 1.0) > 1e-12:
            return 10.0 ** (float(eps[0]) + 400.0)
        return orig(eps)

    system.terms[0].coef._value = value
    res = fit(SteadyProblem(system, M, v), [1.0], formulation="ecfm")
    assert "inner solves failed" in res.message and "overflow" in res.message


def test_ecfm_on_unexplainable_data_says_forces_stayed_large():
    system, M = _heat_system(np.linspace(1.0, 2.0, 8))
    v = np.array([1.0, -2.0, 1.0])  # no diffusion coefficient gives this shape
    res = fit(SteadyProblem(system, M, v), [0.0], formulation="ecfm")
    verdict = res.verdict
    assert verdict.consistent is False
    assert verdict.details["force_to_data"] > 0.1
    assert "NOT consistent" in res.message


def test_ecfm_on_consistent_data_is_consistent():
    system, M = _heat_system(np.linspace(1.0, 2.0, 8))
    v = M @ solve_steady(system, [0.3]).Theta[:, 0]
    res = fit(SteadyProblem(system, M, v), [0.0], formulation="ecfm")
    assert res.success
    verdict = res.verdict
    assert verdict.consistent is True, verdict.message
    assert verdict.details["force_to_data"] < 1e-6
    assert abs(res.eps[0] - 0.3) < 1e-6


def test_verdict_reports_bound_and_extreme_and_peak():
    system, M = _heat_system()
    v = M @ solve_steady(system, [0.0]).Theta[:, 0]
    v[2] += 1.0
    out = consistency_verdict(system, M, v, [-14.0], lam=[0.0, 0.1, -3.0], bounds=[(-14, 2)])
    assert out.details["at_bound"] == [0]
    assert out.details["extreme"] and out.details["extreme"][0][0] == "linear"
    assert out.details["peak_force_index"] == 2
    assert "at a bound" in out.message and "extreme" in out.message
    out = consistency_verdict(system, M, v, [0.0])
    assert out.details["peak_sensor_index"] == 2
    assert not out.consistent


def test_verdict_chi2_for_noisy_data():
    system, M = _heat_system(forces=False)
    v = M @ solve_steady(system, [0.0]).Theta[:, 0]
    noise = np.array([1e-3, -1e-3, 5e-4])
    assert consistency_verdict(system, M, v + noise, [0.0], sigma=1e-3).consistent
    assert not consistency_verdict(system, M, v + 100 * noise, [0.0], sigma=1e-3).consistent


# -- memory: refused before allocating --------------------------------------------------


@pytest.fixture
def small_budget():
    previous = set_memory_budget(2**20)  # 1 MiB
    yield
    set_memory_budget(previous)


def test_dense_E3_refused_beyond_budget(small_budget):
    with pytest.raises(MemoryBudgetError, match="sparse=True"):
        expectation_tensor(ChaosBasis(5, dim=3), 3)  # P = 56: 1.4 MB


def test_sparse_E3_still_allowed_under_budget(small_budget):
    T = expectation_tensor(ChaosBasis(5, dim=3), 3, sparse=True)
    assert T.shape == (56, 56, 56)


def test_tensor_quadrature_refused_beyond_budget(small_budget):
    with pytest.raises(MemoryBudgetError, match="tensor Gauss-Legendre rule with 20\\^4"):
        tensor_gauss_legendre(20, 4)


def test_weighted_gram_refused_beyond_budget(small_budget):
    with pytest.raises(MemoryBudgetError, match="`n_points`"):
        weighted_gram(ChaosBasis(4, dim=3), lambda w: w[:, 0], n_points=40)


def test_large_non_decoupling_dense_system_is_not_solved_dense(small_budget):
    """Dense input, two random inputs in two germs (no decoupling): NP = 40 * 10 = 400,
    a dense Jacobian of 1.2 MiB is over the 1 MiB budget; the engine must pick a
    matrix-free Krylov solver (or refuse with MemoryBudgetError), never allocate it."""
    n = 40
    rng = np.random.default_rng(0)
    A = rng.standard_normal((n, n)) * 0.01
    K0 = np.eye(n) * 4 + A @ A.T
    basis = ChaosBasis(3, dim=2)
    G1 = weighted_gram(basis, lambda w: w[:, 0] - 0.5)
    G2 = weighted_gram(basis, lambda w: w[:, 1] - 0.5)
    system = GalerkinSystem(
        [
            LinearTerm(K0),
            LinearTerm(np.eye(n), G=G1),
            LinearTerm(np.diag(np.linspace(0, 1, n)), G=G2),
            LoadTerm.constant(np.ones(n)),
        ],
        0,
        basis=basis,
    )
    with pytest.raises(MemoryBudgetError):
        system.jacobian(system.zeros(), np.zeros(0))
    sol = solve_steady(system, np.zeros(0))
    assert sol.success
    assert sol.solver.split("+")[0] in {"cg", "gmres"}


# -- hypothesis: malformed input to public constructors ---------------------------------

_ALLOWED = (ValueError, TypeError, ConvergenceError, MemoryBudgetError)

_junk = st.one_of(
    st.none(),
    st.text(max_size=3),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-3, 5),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.lists(st.floats(-2, 2), max_size=3), max_size=3),
    st.builds(lambda s: np.ones(s), st.lists(st.integers(0, 3), max_size=3)),
    st.builds(lambda n: sp.eye(n, format="csr"), st.integers(1, 3)),
    st.complex_numbers(allow_nan=False, allow_infinity=False, max_magnitude=10),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
    st.builds(lambda s: np.full(s, np.nan), st.lists(st.integers(1, 3), min_size=1, max_size=2)),
)


def _call(fn, *args, **kw):
    try:
        fn(*args, **kw)
    except _ALLOWED as e:
        # our messages name the argument (`name`) or the term; numpy's never do
        assert "`" in str(e) or "term" in str(e), f"{type(e).__name__}: {e}"
        assert type(e).__module__.startswith(("builtins", "ecfm_uq")), type(e)


_CONSTRUCTORS = [
    lambda a, b: LinearTerm(a, b),
    lambda a, b: LinearTerm(K, 1.0, G=a),
    lambda a, b: QuadraticTerm(a, b),
    lambda a, b: LoadTerm.constant(a),
    lambda a, b: LoadTerm.scaled(a, b),
    lambda a, b: LoadTerm.linear(a),
    lambda a, b: Coefficient.constant(a),
    lambda a, b: Coefficient.parameter(a, b),
    lambda a, b: Coefficient.power10(a, b),
    lambda a, b: GalerkinSystem([LinearTerm(K), LoadTerm.constant(F)], a, Gamma=b),
    lambda a, b: GalerkinSystem([LinearTerm(K), LoadTerm.constant(F)], 1, M=a),
    lambda a, b: GalerkinSystem([LinearTerm(K), LoadTerm.constant(a)], 0),
    lambda a, b: ChaosBasis(a, b),
    lambda a, b: SolverOptions(solver=a),
    lambda a, b: SolverOptions(rtol=a, maxiter=b),
    lambda a, b: hat_forces(B1, a, b),
    lambda a, b: gaussian_forces(B1, a, b),
    lambda a, b: rbf_forces(TensorBasis2D(SineBasis(2)), a, b),
    lambda a, b: sensor_matrix(B1, a),
    lambda a, b: SineBasis(a),
    lambda a, b: TensorBasis2D(a, b),
    lambda a, b: ChaosBasis(2, index_set=a, normalized=b),
    lambda a, b: expectation_tensor(ChaosBasis(2), a, sparse=b),
    lambda a, b: weighted_gram(ChaosBasis(2), a, n_points=b),
    lambda a, b: Coefficient(a, b),
    lambda a, b: LoadTerm(a, b),
    lambda a, b: sensor_matrix(TensorBasis2D(SineBasis(2)), a),
]


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(which=st.integers(0, len(_CONSTRUCTORS) - 1), a=_junk, b=_junk)
def test_malformed_input_gives_only_clear_errors(which, a, b):
    _call(_CONSTRUCTORS[which], a, b)


_GAMMA_SYSTEM = GalerkinSystem(
    [LinearTerm(K, Coefficient.power10(0)), LoadTerm.constant(F)], 1, Gamma=np.eye(N)[:, :2]
)
_GAMMA_PROBLEM = SteadyProblem(_GAMMA_SYSTEM, np.eye(N)[:2], [1.0, 1.0])
_MASS_SYSTEM = GalerkinSystem([LinearTerm(K), LoadTerm.constant(F)], 1, M=np.eye(N))
_CALLS = [
    lambda a, b: solve_steady(_GAMMA_SYSTEM, a),
    lambda a, b: solve_steady(_GAMMA_SYSTEM, [0.0], lam=a),
    lambda a, b: solve_steady(_GAMMA_SYSTEM, [0.0], tol=a, maxiter=b),
    lambda a, b: solve_steady(_GAMMA_SYSTEM, [0.0], solver=a),
    lambda a, b: solve_steady(_GAMMA_SYSTEM, [0.0], constraint=(a, b)),
    lambda a, b: solve_steady(_GAMMA_SYSTEM, [0.0], Theta0=a),
    lambda a, b: fit(SteadyProblem(_GAMMA_SYSTEM, a, b), [0.0], formulation="ecfm"),
    lambda a, b: fit(_GAMMA_PROBLEM, a, formulation=b),
    lambda a, b: fit(_GAMMA_PROBLEM, [0.0], formulation="ecfm", method=a),
    lambda a, b: fit(_GAMMA_PROBLEM, [0.0], formulation="ecfm", method="L-BFGS-B", bounds=a),
    lambda a, b: fit(_GAMMA_PROBLEM, [0.0], formulation="ecfm", tol=a, maxiter=b),
    lambda a, b: march(_MASS_SYSTEM, [0.0], a, 0.1, 2),
    lambda a, b: march(_MASS_SYSTEM, [0.0], np.zeros(N), a, b),
    lambda a, b: consistency_verdict(_GAMMA_SYSTEM, np.eye(N)[:2], [1.0, 1.0], [0.0], a, b),
    lambda a, b: consistency_verdict(_GAMMA_SYSTEM, np.eye(N)[:2], a, [0.0], sigma=b),
]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(which=st.integers(0, len(_CALLS) - 1), a=_junk, b=_junk)
def test_malformed_solver_arguments_give_only_clear_errors(which, a, b):
    _call(_CALLS[which], a, b)


def test_every_mistake_is_documented():
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "mistakes.md").read_text()
    missing = [m[0] for m in MISTAKES if f"| {m[0]} |" not in doc]
    assert not missing, f"add to docs/mistakes.md: {missing}"
