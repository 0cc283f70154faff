"""The ModelProblem fit's drivers (issue 38 item 5, issue 37 item 7): MINPACK's
Levenberg-Marquardt without bounds, the trust region with them, one status test after
either, judged on central differences when the fit's are one-sided.

Truth: scipy's ``curve_fit`` (MINPACK, independent of this library's status and
uncertainty code), NIST's certified values and complex-step derivatives.
"""

import warnings

import numpy as np
import pytest
from _nist_strd import load
from scipy import optimize

from ecfm_uq.inverse import FitStatus, ModelProblem, fit
from ecfm_uq.inverse.core.levenberg_marquardt import LM_STEP_TOL

X = np.linspace(0.0, 5.0, 22)
START = np.array([1.0, 1.0])


def decay(e):
    return e[0] * np.exp(-e[1] * X)


@pytest.fixture(scope="module")
def data():
    return decay(np.array([2.0, 0.7])) + 0.05 * np.random.default_rng(0).standard_normal(X.size)


def test_levenberg_marquardt_and_trust_region_give_curve_fits_answer(data):
    """The default (LM, no bounds) and method='trf' end at one optimum, curve_fit's, with
    its standard errors; both by the same test (relative offset <= 1e-6)."""
    lm = fit(ModelProblem(decay, data), START)
    trf = fit(ModelProblem(decay, data), START, method="trf")
    popt, pcov = optimize.curve_fit(lambda x, a, b: a * np.exp(-b * x), X, data, p0=START)
    for res in (lm, trf):
        assert res.status is FitStatus.CONVERGED and res.optimality <= 1e-6, res.message
    assert "Levenberg-Marquardt" in lm.message and "Levenberg-Marquardt" not in trf.message
    # each within c sqrt(p) standard errors of the optimum (its status's certificate):
    # c <= 1e-6 and SE/eps ~ 0.02 put both within 3e-8 relative; curve_fit stops on its
    # own 1.5e-8 relative tolerances
    np.testing.assert_allclose(lm.eps, trf.eps, rtol=1e-7)
    np.testing.assert_allclose(lm.eps, popt, rtol=1e-6)
    # s^2 (J^T J)^-1 with central differences at the estimate vs curve_fit's (MINPACK's
    # one-sided Jacobian: ~1e-7 relative error)
    np.testing.assert_allclose(lm.uncertainty.stderr, np.sqrt(np.diag(pcov)), rtol=1e-5)


def test_lm_is_for_unbounded_fits_and_bounds_take_the_trust_region(data):
    with pytest.raises(ValueError, match="method='trf'"):
        fit(ModelProblem(decay, data), START, method="lm", bounds=[(0, 5), (0, 5)])
    boxed = fit(ModelProblem(decay, data), [1.0, 0.5], bounds=[(0, 5), (0, 0.6)])
    assert boxed.success and boxed.eps[1] == pytest.approx(0.6)
    assert "Levenberg-Marquardt (MINPACK)" not in boxed.message


def test_lm_budget_spent_is_max_iterations(data):
    res = fit(ModelProblem(decay, data), START, maxiter=3)
    assert res.status is FitStatus.MAX_ITERATIONS and not res.success
    assert "NOT converged" in res.message


@pytest.mark.parametrize("start", [0, 1])
def test_one_sided_fits_are_judged_on_central_differences(start):
    """NIST Lanczos3 with one-sided differences: their Jacobian's error moves the point
    where J^T r = 0 by ~3e-6 relative (and OPENBLAS_CORETYPE=Haswell then ended CONVERGED
    there, 1e-6 asked). The status test and the last steps use central differences, so a
    CONVERGED fit is the complex-step fit's optimum to what both statuses certify, and its
    standard errors (from the judged, central Jacobian) are the complex-step ones."""
    P = load("Lanczos3")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fd = fit(ModelProblem(P.f, P.y), P.starts[start])
        cs = fit(ModelProblem(P.f, P.y, jac="cs"), P.starts[start])
    assert fd.success and cs.success, fd.message
    # each estimate within c sqrt(p) standard errors of its stationary point (Cauchy-
    # Schwarz on the Gauss-Newton step, c its relative offset), and the one-sided fit's,
    # judged on central differences, moved from the optimum by their own error,
    # (J^T J)^{-1} dJ^T r with dJ measured against the complex-step Jacobian: ~1e-9
    # relative on Lanczos3 (its conditioning), the same size as the offsets' share once
    # both fits are polished to ~1e-8 (the one-sided Jacobian's 3e-6 is far above)
    p = P.certified.size
    certified = (fd.optimality + cs.optimality) * np.sqrt(p) * cs.uncertainty.stderr
    problem = ModelProblem(P.f, P.y)
    J_cs = ModelProblem(P.f, P.y, jac="cs").jacobian(fd.eps)
    dJ = problem.jacobian(fd.eps, method="3-point") - J_cs
    shift = np.linalg.solve(J_cs.T @ J_cs, dJ.T @ (P.f(fd.eps) - P.y))
    assert np.all(np.abs(fd.eps - cs.eps) <= certified + np.abs(shift)), (
        fd.eps - cs.eps, certified, shift)  # fmt: skip
    np.testing.assert_allclose(fd.eps, P.certified, rtol=1e-6)
    # one-sided differences' standard errors were 5e-6 off the complex-step ones
    np.testing.assert_allclose(fd.uncertainty.stderr, cs.uncertainty.stderr, rtol=1e-6)


def test_a_stalled_levenberg_marquardt_falls_back_to_the_trust_region():
    """NIST BoxBOD from start 1 with one-sided differences: MINPACK's first steps send the
    rate to infinity (STALLED, rank-deficient J); the trust region from the start reaches
    the certified values."""
    P = load("BoxBOD")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = fit(ModelProblem(P.f, P.y), P.starts[0])
        lm = fit(ModelProblem(P.f, P.y), P.starts[0], method="lm")
    assert lm.status is FitStatus.STALLED
    assert res.success and "Levenberg-Marquardt stalled" in res.message
    np.testing.assert_allclose(res.eps, P.certified, rtol=1e-6)


@pytest.mark.parametrize(("name", "start"), [("Nelson", 1), ("Roszman1", 0), ("Roszman1", 1)])
def test_minpacks_stop_is_brought_to_the_certified_values(name, start):
    """MINPACK stops on a relative decrease of the sum of squares (``LM_FTOL`` = 1e-10),
    where these NIST fits' estimates are still 4e-7 to 1.3e-6 from their certified values
    while the status test already holds. The Gauss-Newton step on the status test's
    Jacobian measures that distance; above ``LM_STEP_TOL`` (1e-7) the fit takes the
    polish's steps and lands within it of NIST's values (without the polish,
    ``polish=False``, it does not: the test can fail)."""
    P = load(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = fit(ModelProblem(P.f, P.y), P.starts[start])
        raw = fit(ModelProblem(P.f, P.y), P.starts[start], options={"polish": False})
    assert res.success and raw.success and "brought below 1e-07" in res.message, res.message
    err = np.max(np.abs(res.eps / P.certified - 1))
    raw_err = np.max(np.abs(raw.eps / P.certified - 1))
    assert err <= LM_STEP_TOL < 3e-7 < raw_err, (err, raw_err)


def test_a_model_in_pascals_ends_where_minpack_run_to_round_off_does():
    """A model built apart from ours, from the docs alone: a creep law in SI units,
    strain = (F/E)(1 - exp(-t/tau)), E ~ 2.1e11 Pa, readings ~2e-8 with 1 % noise,
    one-sided differences. MINPACK stops at ``LM_FTOL`` = 1e-10 and the status test
    judges (and refines where needed): the estimate equals scipy's ``curve_fit`` run to
    round-off (ftol = xtol = gtol = 1e-15) within ``LM_STEP_TOL``, and the standard
    errors its covariance's within 1e-6."""
    t = np.linspace(0.5, 20.0, 25)

    def law(t, E, tau):
        return (5.0e3 / E) * (1.0 - np.exp(-t / tau))

    y = law(t, 2.1e11, 3.0) * (1 + 0.01 * np.random.default_rng(7).standard_normal(t.size))
    res = fit(ModelProblem(lambda e: law(t, *e), y), [1.5e11, 5.0])
    ref, cov = optimize.curve_fit(law, t, y, p0=[1.5e11, 5.0], ftol=1e-15, xtol=1e-15,
                                  gtol=1e-15)  # fmt: skip
    assert res.status is FitStatus.CONVERGED, res.message
    np.testing.assert_allclose(res.eps, ref, rtol=LM_STEP_TOL)
    np.testing.assert_allclose(res.uncertainty.stderr, np.sqrt(np.diag(cov)), rtol=1e-6)


def _peak_on_a_background():
    x = np.linspace(-3.0, 3.0, 40)

    def peak(e):
        return e[0] * np.exp(-0.5 * ((x - e[1]) / e[2]) ** 2) + e[3]

    y = peak([2.0, 0.3, 0.8, 0.5]) + 0.05 * np.random.default_rng(1).standard_normal(x.size)
    return peak, y, np.array([1.5, 0.0, 1.0, 0.3])


def _relaxation_in_seconds():
    """One parameter in SI units: a relaxation rate k ~ 2.5e9 1/s read over nanoseconds."""
    t = np.linspace(0.0, 2e-9, 30)

    def relax(e):
        return 3e-3 * np.exp(-e[0] * t)

    y = relax([2.5e9]) * (1 + 0.01 * np.random.default_rng(4).standard_normal(t.size))
    return relax, y, np.array([1.0e9])


@pytest.mark.parametrize("problem", [_peak_on_a_background, _relaxation_in_seconds])
def test_minpacks_jacobian_columns_stay_out_of_the_path(problem):
    """With one-sided differences MINPACK (lmdif) evaluates the p columns of its Jacobian
    right after each accepted point; the fit counts them as one Jacobian per iterate and
    keeps them out of its path (p = 4, and p = 1 in SI units: a Jacobian of one column).
    Truth: scipy's ``leastsq`` with the same settings, its calls recorded and the columns
    told apart here by their definition (the point before them moved by sqrt(machine
    eps)|x_j| in coordinate j alone, j = 0, 1, ... in turn)."""
    peak, y, start = problem()
    res = fit(ModelProblem(peak, y), start)
    calls = []

    def recorded(e):
        calls.append(np.array(e))
        return peak(e) - y

    from ecfm_uq.inverse.core.levenberg_marquardt import LM_FTOL

    info = optimize.leastsq(recorded, start, ftol=LM_FTOL, xtol=1e-15, gtol=1e-15,
                            full_output=True)[2]  # fmt: skip
    while calls[1].tobytes() == start.tobytes():  # leastsq's shape checks at the start
        calls.pop(0)
    h = np.sqrt(np.finfo(float).eps)
    path, jacobians, base, column = [], 0, None, None
    for e in calls:
        if base is not None:
            j = 0 if column is None else column + 1
            moved = base.copy()
            moved[j] = base[j] + (h * abs(base[j]) or h)
            if e.tobytes() == moved.tobytes():
                column = None if j == e.size - 1 else j
                jacobians += j == e.size - 1
                continue
        base, column = e, None
        path.append(e)
    losses = [0.5 * float(np.sum((peak(e) - y) ** 2)) for e in path]
    improving = [e for k, e in enumerate(path) if losses[k] < min(losses[:k], default=np.inf)]
    assert res.success and "brought below" not in res.message, res.message
    assert res.nit == jacobians >= 3
    np.testing.assert_array_equal(res.eps_history, np.array(improving))
    # MINPACK's evaluations and the status test's central differences, 2 per parameter
    assert len(calls) == info["nfev"] and res.nfev == info["nfev"] + 2 * start.size
