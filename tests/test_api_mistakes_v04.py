"""The hard edges of the v0.4 front door (issue 39; documented in docs/mistakes.md).

Every case of the issue's catalogue that was a silent wrong answer, a hang or an unclear
message: each silent case is now refused (or right, checked against an independent
truth), each hang a reported failure within seconds, each message names the argument
and the fix. ``python tests/test_api_mistakes_v04.py`` prints the table of
docs/mistakes.md from the messages these cases raise now.

Examples: Michaelis-Menten on the Puromycin data (Bates & Watts 1988; V_max 212.68,
K 0.06412) and f = x0 + 2 x1 on U(0, 1)^2 (first-order Sobol indices 1/5 and 4/5).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy import optimize, stats

from ecfm_uq.chaos import Inputs, fit_pce
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.inverse import DynamicInverseProblem, ModelProblem, fit, profile_likelihood
from ecfm_uq.mc import monte_carlo, sobol_indices
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, NonlinearTerm, integrate
from ecfm_uq.system.step_control import choose_steps

CONC = np.array([0.02, 0.02, 0.06, 0.06, 0.11, 0.11, 0.22, 0.22, 0.56, 0.56, 1.10, 1.10])
RATE = np.array([76, 47, 97, 107, 123, 139, 159, 152, 191, 201, 207, 200], dtype=float)
E0 = [200.0, 0.1]
U2 = [(0.0, 1.0), (0.0, 1.0)]


def mm(e):
    return e[0] * CONC / (e[1] + CONC)


def lin(x):
    return x[0] + 2.0 * x[1]


def _fit():
    return fit(ModelProblem(mm, RATE, names=["V_max", "K"]), E0)


_RES = {}


def res():
    """The Michaelis-Menten fit (computed once)."""
    if "mm" not in _RES:
        _RES["mm"] = _fit()
    return _RES["mm"]


def other_profile():
    """The profile of a fit to other data (rates 10 % higher)."""
    if "other" not in _RES:
        _RES["other"] = profile_likelihood(fit(ModelProblem(mm, 1.1 * RATE), E0))
    return _RES["other"]


class TwiceDensity(stats.rv_continuous):
    """A user's law whose density 4x on [0, 1] integrates to 2."""

    def _pdf(self, x):
        return 4.0 * x


class TriangleDensity(stats.rv_continuous):
    """The same law normalized: density 2x on [0, 1], mean 2/3."""

    def _pdf(self, x):
        return 2.0 * x


def blow_up_system():
    """u' = u^2 - u from u(0) = 1.1 blows up at t = ln 11 = 2.398, before t = 3."""
    term = NonlinearTerm(
        lambda u, w, e: u * (1 - u), lambda u, w, e: np.array([[1 - 2 * u[0]]]),
        eps_jacobian=lambda u, w, e: np.zeros((1, 1)), size=1,
    )  # fmt: skip
    return GalerkinSystem([term], 1, M=np.eye(1), name="blow-up")


def singular_mass_system():
    K = np.diag([2.0, 3.0, 4.0])
    return GalerkinSystem(
        [LinearTerm(K), LoadTerm.constant(np.ones(3))], 0, M=np.diag([1.0, 0.0, 1.0])
    )


# (id, callable, exception type, words that must appear in the message)
MISTAKES_V04 = [
    # -- silent wrong answers, now refused --------------------------------------------------
    ("model returns complex values",
     lambda: fit(ModelProblem(lambda e: mm(e) * np.exp(0.5j), RATE), E0),
     TypeError, "`model` at eps=[2.e+02 1.e-01] returned complex values"),
    ("flat prediction of 2-D data",
     lambda: fit(ModelProblem(mm, RATE.reshape(6, 2)), E0),
     ValueError, "returned shape (12,); the data have shape (6, 2)"),
    ("profile max_steps=0", lambda: profile_likelihood(res(), max_steps=0),
     ValueError, "`max_steps` must be >= 1, got 0"),
    ("summary level=1.5", lambda: res().summary(level=1.5),
     ValueError, "`level` must be in (0, 1), a fraction"),
    ("summary level=95", lambda: res().summary(level=95),
     ValueError, "a percentage? pass 0.95"),
    ("summary of another fit's profile", lambda: res().summary(profile=other_profile()),
     ValueError, "`profile` was computed for another fit"),
    ("sobol_indices n=2", lambda: sobol_indices(lin, U2, 2, seed=0),
     ValueError, "`n` = 2 is too small for Sobol indices"),
    ("sobol_indices on a law without variance",
     lambda: sobol_indices(lin, [stats.cauchy(), stats.norm()], 64, seed=0),
     ValueError, "input 'x0' (cauchy()) has no finite mean: sobol_indices needs"),
    ("sobol_indices on t(2) (a mean, no variance)",
     lambda: sobol_indices(lin, [stats.t(2.0), stats.norm()], 64, seed=0),
     ValueError, "input 'x0' (t(2.0,)) has no finite variance: sobol_indices needs"),
    ("fit_pce on pareto(0.5)", lambda: fit_pce(lambda x: x[0], [stats.pareto(0.5)], seed=0),
     ValueError, "has no finite mean: fit_pce needs a mean"),
    ("fit_pce on cauchy()", lambda: fit_pce(lambda x: x[0], [stats.cauchy()], seed=0),
     ValueError, "input 'x0' (cauchy()) has no finite mean"),
    ("density integrating to 2",
     lambda: fit_pce(lambda x: x[0], [TwiceDensity(a=0.0, b=1.0)], seed=0),
     ValueError, "its density integrates to 2 over [0, 1], not 1"),
    # -- unclear messages, now naming the argument and the fix -------------------------------
    ("bounds exclude eps0", lambda: fit(ModelProblem(mm, RATE), E0, bounds=[(0, 100), (0, 1)]),
     ValueError, "`eps0[0]` = 200 lies outside `bounds[0]` = (0, 100)"),
    ("bounds with lo = hi",
     lambda: fit(ModelProblem(mm, RATE), E0, bounds=[(200, 200), (0, 1)]),
     ValueError, "`bounds[0]` has lo == hi == 200"),
    ("options x_scale='auto'",
     lambda: fit(ModelProblem(mm, RATE), E0, options={"x_scale": "auto"}),
     ValueError, "options['x_scale'] must be 'jac'"),
    ("profile which a wrong name", lambda: profile_likelihood(res(), which=["Vmax"]),
     ValueError, "`which` names 'Vmax', not a parameter name; the names are ['V_max', 'K']"),
    ("profile bounds exclude the estimate",
     lambda: profile_likelihood(res(), bounds=[(0, 100), (0, 1)]),
     ValueError, "`bounds[0]` = (0.0, 100.0) excludes the estimate eps[0] = 212.684"),
    ("summary level='95%'", lambda: res().summary(level="95%"),
     TypeError, "`level` must be a number in (0, 1) (e.g. 0.95), got str '95%'; pass 0.95"),
    ("integrate with a singular mass matrix",
     lambda: integrate(singular_mass_system(), [], np.zeros(3), np.linspace(0, 1, 3)),
     ValueError, "the mass matrix `M` of the system is singular (rank 2 < N = 3)"),
    ("choose_steps given times=",
     lambda: choose_steps(blow_up_system(), [0.0], [1.0], times=[0.0, 1.0, 2.0]),
     TypeError, "choose_steps takes the data times as `t_data`"),
    ("seed a string", lambda: sobol_indices(lin, U2, 64, seed="abc"),
     TypeError, "`seed` must be a seed, got str 'abc'"),
    ("seed negative", lambda: fit_pce(lin, U2, seed=-1),
     ValueError, "`seed` must be >= 0, got -1"),
    ("pointwise model with vectorized=True",
     lambda: sobol_indices(lin, U2, 64, seed=0, vectorized=True),
     IndexError, "with vectorized=True `model` receives a (k, d) array"),
    ("vectorized model without vectorized=True",
     lambda: sobol_indices(lambda X: X[:, 0] + 2 * X[:, 1], U2, 64, seed=0),
     IndexError, "(pass vectorized=True for a function of a (k, d) array of points)"),
    ("model reads more inputs than given",
     lambda: fit_pce(lambda x: x[0] + x[2], U2, seed=0),
     IndexError, "check that it reads no more inputs than there are"),
    ("model returns None", lambda: fit(ModelProblem(lambda e: None, RATE), E0),
     TypeError, "returned None; `model` must return its values"),
    ("monte_carlo fn returns None", lambda: monte_carlo(lambda x: None, np.ones((4, 1)), workers=1),
     TypeError, "`fn` at sample 0 (x=[1.]) returned None"),
    ("model returns a tuple", lambda: fit(ModelProblem(lambda e: (mm(e), 0), RATE), E0),
     TypeError, "returned a tuple of 2 items"),
    ("law class instead of an instance",
     lambda: sobol_indices(lin, [TriangleDensity, stats.norm()], 64, seed=0),
     TypeError, "is the class TriangleDensity, not a law: pass an instance"),
    ("inputs as a dict",
     lambda: sobol_indices(lin, {"a": (0, 1), "b": (0, 1)}, 64, seed=0),
     TypeError, "got a dict of 2 entries; pass Inputs(list(d.values()), names=list(d))"),
    ("choose_steps on a blow-up",
     lambda: choose_steps(blow_up_system(), [0.0], [1.1], np.linspace(0, 3, 4)),
     ConvergenceError, "the solution left the region where the model can be marched near t="),
    ("jac='cs' on a model with abs",
     lambda: fit(ModelProblem(lambda e: np.abs(e[0]) * CONC / (e[1] + CONC), RATE, jac="cs"),
                 E0),
     ValueError, "`model` is not complex-analytic in it"),
]  # fmt: skip


def test_catalogue_is_complete():
    assert len(MISTAKES_V04) >= 30
    assert len({m[0] for m in MISTAKES_V04}) == len(MISTAKES_V04)


@pytest.mark.parametrize(
    ("fn", "exc", "words"), [m[1:] for m in MISTAKES_V04], ids=[m[0] for m in MISTAKES_V04]
)
def test_mistake_v04(fn, exc, words):
    with pytest.raises(exc) as info:
        fn()
    assert words in str(info.value)


def test_a_users_error_is_chained_and_keeps_its_type():
    def model(x):
        raise KeyError("missing table")

    with pytest.raises(KeyError) as info:
        sobol_indices(model, U2, 64, seed=0)
    assert "`model` at sample 0 (x=[" in str(info.value)
    assert isinstance(info.value.__cause__, KeyError)


# -- silent cases now right, against an independent truth ------------------------------------


def _puromycin_scipy():
    tight = dict(xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return optimize.least_squares(lambda e: mm(e) - RATE, E0, **tight).x


def test_2d_data_with_a_2d_prediction_is_the_flat_fit():
    two_d = fit(ModelProblem(lambda e: mm(e).reshape(6, 2), RATE.reshape(6, 2)), E0)
    assert two_d.success
    np.testing.assert_allclose(two_d.eps, _puromycin_scipy(), rtol=1e-6)
    np.testing.assert_allclose(two_d.eps, res().eps, rtol=1e-10)


def test_a_model_that_reuses_its_output_buffer_fits_as_a_fresh_one():
    out = np.empty(CONC.size)

    def shared(e):
        out[:] = mm(e)
        return out

    r = fit(ModelProblem(shared, RATE), E0)
    assert r.success, r.message
    np.testing.assert_allclose(r.eps, _puromycin_scipy(), rtol=1e-6)
    np.testing.assert_allclose(r.eps, res().eps, rtol=1e-10)


def test_sobol_indices_of_a_buffer_reusing_model_equal_a_fresh_model():
    buf = np.empty(1)

    def shared(x):
        buf[0] = lin(x)
        return buf

    a = sobol_indices(shared, U2, 1024, seed=0)
    b = sobol_indices(lin, U2, 1024, seed=0)
    np.testing.assert_array_equal(a.first_order[:, 0], b.first_order)
    # first-order indices of x0 + 2 x1 on U(0,1)^2: 1/5 and 4/5, inside the intervals
    lo, hi = b.first_order_interval
    assert np.all((lo <= [0.2, 0.8]) & ([0.2, 0.8] <= hi))


def test_fit_pce_of_a_buffer_reusing_model_is_exact():
    buf = np.empty(1)

    def shared(x):
        buf[0] = lin(x)
        return buf

    pce = fit_pce(shared, U2, "lstsq", order=1, seed=0)
    # mean 1.5, variance 1/12 + 4/12 of x0 + 2 x1: a degree-1 expansion is exact
    assert float(np.ravel(pce.mean)[0]) == pytest.approx(1.5, rel=1e-12)
    assert float(np.ravel(pce.variance)[0]) == pytest.approx(5.0 / 12.0, rel=1e-10)


def test_a_normalized_user_density_is_accepted_and_its_mean_is_the_laws():
    pce = fit_pce(lambda x: x[0], Inputs([TriangleDensity(a=0.0, b=1.0)]), "quadrature", order=3)
    assert float(pce.mean) == pytest.approx(2.0 / 3.0, rel=1e-6)


def test_a_heavy_tailed_input_with_a_mean_still_fits_and_profile_which_takes_names():
    # Student t(3): mean 0, variance 3 (finite): both checks pass
    pce = fit_pce(lambda x: x[0], Inputs([stats.t(3.0)]), "quadrature", order=1)
    assert abs(float(pce.mean)) < 1e-10
    by_name = profile_likelihood(res(), which=["K"])
    by_index = profile_likelihood(res(), which=[1])
    np.testing.assert_array_equal(by_name.intervals, by_index.intervals)


def test_a_complex_step_model_may_return_a_complex_array_at_real_parameters():
    def mm_complex(e):
        out = np.zeros(CONC.size, dtype=complex)
        out[:] = e[0] * CONC / (e[1] + CONC)
        return out

    r = fit(ModelProblem(mm_complex, RATE, jac="cs"), E0)
    assert r.success, r.message
    np.testing.assert_allclose(r.eps, _puromycin_scipy(), rtol=1e-6)


def test_the_summary_takes_this_fits_own_profile():
    text = res().summary(profile=profile_likelihood(res()))
    assert "profile" in text and "95 % interval" in text


# -- hangs, now reported failures ----------------------------------------------------------


def test_choose_steps_on_a_blow_up_fails_quickly_naming_the_time():
    t0 = time.perf_counter()
    with pytest.raises(ConvergenceError, match=r"left the region .* near t=2\.\d+") as info:
        choose_steps(blow_up_system(), [0.0], [1.1], np.linspace(0, 3, 4))
    assert time.perf_counter() - t0 < 60  # issue 39: a failure within 60 s, not a hang
    # the time named lies before the blow-up at ln 11
    t_named = float(str(info.value).split("near t=")[1].split(":")[0])
    assert 2.0 < t_named < np.log(11.0)


def test_an_adaptive_fit_from_a_blow_up_start_is_a_reported_failure():
    problem = DynamicInverseProblem(
        blow_up_system(), [1.1], 1.0, 3, np.eye(1), np.ones((4, 1)), scheme="adaptive"
    )
    t0 = time.perf_counter()
    r = fit(problem, [0.0])
    assert time.perf_counter() - t0 < 60  # issue 39: a failure within 60 s, not a hang
    assert not r.success
    assert "left the region where the model can be marched near t=2." in r.message


def test_choose_steps_failure_loop_respects_max_steps():
    with pytest.raises(ConvergenceError, match="would exceed max_steps=40"):
        choose_steps(blow_up_system(), [0.0], [1.1], np.linspace(0, 3, 4), max_steps=40)


def _buffer_sobol():
    buf = np.empty(1)

    def shared(x):
        buf[0] = lin(x)
        return buf

    r = sobol_indices(shared, U2, 1024, seed=0)
    return f"first order {np.round(r.first_order[:, 0], 3).tolist()} (truth [0.2, 0.8])"


def _buffer_pce():
    buf = np.empty(1)

    def shared(x):
        buf[0] = lin(x)
        return buf

    pce = fit_pce(shared, U2, "lstsq", order=1, seed=0)
    return f"mean {float(np.ravel(pce.mean)[0]):.6g} (truth 1.5)"


def _buffer_fit():
    out = np.empty(CONC.size)

    def shared(e):
        out[:] = mm(e)
        return out

    r = fit(ModelProblem(shared, RATE), E0)
    return f"success={r.success}, eps {np.round(r.eps, 4).tolist()} (scipy: 212.6837, 0.0641)"


def _adaptive_blow_up():
    problem = DynamicInverseProblem(
        blow_up_system(), [1.1], 1.0, 3, np.eye(1), np.ones((4, 1)), scheme="adaptive"
    )
    r = fit(problem, [0.0])
    return f"success={r.success}, status {r.status.name}: {r.message}"


#: the cases that now return the right answer or a reported failure: (id, what they give)
NOW_RIGHT = [
    ("sobol_indices of a model reusing its output array", _buffer_sobol),
    ("fit_pce of a model reusing its output array", _buffer_pce),
    ("ModelProblem of a model reusing its output array", _buffer_fit),
    ("adaptive fit from a start that blows up", _adaptive_blow_up),
]


def _table():
    """The markdown rows of docs/mistakes.md: each case and the message it gives now."""
    rows = []
    for name, fn, _exc, _words in MISTAKES_V04:
        try:
            fn()
        except Exception as e:  # the message is the point
            msg = f"{type(e).__name__}: {e}"
        else:
            msg = "(no error)"
        rows.append((name, msg))
    rows += [(name, fn()) for name, fn in NOW_RIGHT]
    return [
        f"| {name} | `` {' '.join(msg.split()).replace('|', chr(92) + '|')} `` |"
        for name, msg in rows
    ]


def test_every_v04_mistake_is_documented():
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "mistakes.md").read_text()
    names = [m[0] for m in MISTAKES_V04] + [m[0] for m in NOW_RIGHT]
    missing = [name for name in names if f"| {name} |" not in doc]
    assert not missing, f"add to docs/mistakes.md: {missing}"


if __name__ == "__main__":
    print("\n".join(_table()))
