"""``ecfm-uq reproduce ode``: the ODE ECFM's verdict, force map and term discovery on
synthetic Lotka-Volterra data (issue 36).

Three experiments, each over ``n_datasets`` noise draws (:func:`ecfm_uq.inverse.fit`
with ``formulation="ecfm"`` on an :class:`~ecfm_uq.inverse.OdeProblem` with the exact
Jacobians of :mod:`ecfm_uq.problems.lotka_volterra`):

* ``correct``: data from the fitted model itself (annual over 20 years, monthly over 10,
  ``relative_noise`` of known sigma): the false-alarm rate of the forces' chi-squared test
  at alpha = 0.05, with its Clopper-Pearson 95 % interval, and alike of the random-force
  ECFM's (``formulation="ecfm-random"``) restricted likelihood-ratio test of tau = 0
  against the 50:50 chi-squared mixture (``random_flagged``: the mixture's actual size;
  a parametric bootstrap of that test per data set would cost a random-force fit per
  replicate, hundreds per data set, beyond this study's budget);
* ``harvest``: the prey harvested, ``du/dt -= harvest * u`` on ``window``, which the model
  lacks: the share of data sets flagged (verdict not consistent) and located (a
  significant force window on the prey inside ``window`` widened by a year each side),
  and the share the random-force ECFM flags;
* ``missing_term``: logistic prey growth ``du/dt = a u - k u^2 - b u v`` in the data,
  plain LV fitted, monthly over 10 years: the share of data sets for which
  :func:`~ecfm_uq.inverse.discover_terms` selects ``u^2`` in the prey equation with a
  coefficient within ``coef_tolerance`` of ``-k`` (terms outside ``u, u^2, u*v``, which
  the fit's shifted ``a, b`` explain, are counted apart).

Every draw's fits start from the truth's fits (the estimates on the noise-free data) and
stop at a relative change of 1e-10 (:data:`FIT_OPTIONS`; the status test decides as
always). The simulation of the data (:func:`simulate`) is part of the study, so the tests import
it rather than keep a copy. This module only reads settings, calls the library and draws
the figure.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.stats import binomtest

from ..inverse import OdeProblem, discover_terms, fit
from ..plotting import pyplot, save_figure
from ..problems.lotka_volterra import initial_state, jac_eps, jac_y, rhs

__all__ = ["TRUTH", "LOGISTIC_TRUTH", "lv_problem", "simulate"]

NAME = "ode"
DESCRIPTION = (
    "Issue 36: Lotka-Volterra ECFM fits over many noise draws: false-alarm rate on the "
    "correct model, a left-out harvest flagged and located, a missing logistic term named"
)

#: (a, b, c, d, u0, v0) of the correct-model and harvest data
TRUTH = (0.5, 0.025, 0.025, 0.8, 30.0, 4.0)
#: (a, b, c, d, u0, v0) and k of the logistic-prey data (docs/discover_terms.md)
LOGISTIC_TRUTH = (1.0, 0.5, 0.25, 0.5, 4.0, 1.0)

DEFAULTS = {
    "seed": 0,
    "n_datasets": 100,
    "relative_noise": 0.03,
    "annual_years": 20,
    "monthly_years": 10,
    "harvest": 0.6,
    "window": [5.0, 8.0],
    "logistic_k": 0.1,
    "missing_noise": 0.01,  # relative noise of the logistic-prey data
    "coef_tolerance": 0.25,
    "rtol": 1e-7,
}
#: the fits' stopping: a relative change of 1e-10 (the default 1e-15 runs to round-off);
#: the status test (relative offset 1e-6, polished where it fails) decides as before,
#: and the verdicts' p-values agree with the default's to ~1e-7
FIT_OPTIONS = {"ftol": 1e-10, "xtol": 1e-10, "gtol": 1e-10}
ALARM_CLAIM = (0.01, 0.10)  # issue 36: the false-alarm rate inside this range
POWER_CLAIM = 0.95  # flagged, located, term found in at least this share


def simulate(times, eps=TRUTH, harvest=0.0, window=(5.0, 8.0), push=None, logistic=0.0):
    """Lotka-Volterra states at ``times``, solved to 1e-12.

    Parameters
    ----------
    times : (n,) array_like
        Increasing output times; the solution starts at ``times[0]`` from ``eps[4:6]``.
    eps : sequence of 6 floats, optional
        ``(a, b, c, d, u0, v0)``.
    harvest : float, optional
        ``du/dt -= harvest * u`` while ``window[0] <= t < window[1]``.
    window : (2,) sequence, optional
        The harvest's time window.
    push : (2,) array_like, optional
        A constant force added to the right-hand side throughout.
    logistic : float, optional
        ``du/dt -= logistic * u**2`` throughout (logistic prey growth).

    Returns
    -------
    (n, 2) ndarray
    """
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or times.size < 2 or np.any(np.diff(times) <= 0):
        raise ValueError("`times` must be an increasing 1-D array of at least 2 times")
    eps = np.asarray(eps, dtype=float)
    add = np.zeros(2) if push is None else np.asarray(push, dtype=float)

    def f(t, y):
        h = harvest if window[0] <= t < window[1] else 0.0
        return rhs(t, y, eps) + add - np.array([h * y[0] + logistic * y[0] ** 2, 0.0])

    cuts = sorted({times[0], times[-1], *[w for w in window if times[0] < w < times[-1]]})
    y, out = eps[4:6], []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        sel = times[(times >= a) & ((times < b) | (b == times[-1]))]
        s = solve_ivp(f, (a, b), y, method="DOP853", rtol=1e-12, atol=1e-12,
                      t_eval=sel, dense_output=True)  # fmt: skip
        out.append(s.y.T)
        y = s.sol(b)
    return np.vstack(out)


def lv_problem(times, data, rtol=1e-9, **kw):
    """The :class:`~ecfm_uq.inverse.OdeProblem` of Lotka-Volterra with its Jacobians
    (states ``hare, lynx`` unless ``state_names``; ``t0 = times[0]``, ``atol = rtol`` unless given)."""
    kw.setdefault("jac", (jac_y, jac_eps))
    kw.setdefault("state_names", ["hare", "lynx"])
    return OdeProblem(rhs, initial_state, times, data, t0=kw.pop("t0", times[0]), rtol=rtol,
                      atol=kw.pop("atol", rtol), **kw)  # fmt: skip


def add_arguments(parser):
    """Study options (``ecfm-uq reproduce ode --help``)."""
    parser.add_argument(
        "--n-datasets",
        type=int,
        default=DEFAULTS["n_datasets"],
        help="noise draws per experiment and sampling (default "
        f"{DEFAULTS['n_datasets']}, what reproduce all's ten minutes allow; the issue's "
        "claim is about >= 100)",
    )


def settings_from_args(args):
    """Validate the options and return the settings recorded in ``result.json``."""
    s = dict(DEFAULTS)
    s["seed"] = DEFAULTS["seed"] if args.seed is None else int(args.seed)
    if s["seed"] < 0:
        raise ValueError(f"--seed must be non-negative, got {s['seed']}")
    if args.n_datasets < 1:
        raise ValueError(f"--n-datasets must be a positive integer, got {args.n_datasets}")
    s["n_datasets"] = int(args.n_datasets)
    return s


def _rate(k, n):
    ci = binomtest(int(k), int(n)).proportion_ci(0.95, method="exact")
    return {"count": int(k), "n": int(n), "rate": k / n, "ci95": [ci.low, ci.high]}


def _samplings(s):
    return {
        "annual": np.arange(0.0, s["annual_years"] + 0.5),
        "monthly": np.arange(0.0, s["monthly_years"] + 1e-9, 1 / 12),
    }


def _located(res, window):
    lo, hi = window[0] - 1.0, window[1] + 1.0
    return any(n == "hare" and a >= lo and b <= hi for n, (a, b), _ in
               res.extra["significant_forces"])  # fmt: skip


def _starts(times, clean, sigma, s):
    """The truth's fits, every draw's starts: the ECFM and the least-squares estimates
    on the noise-free data (the random-force ECFM starts with a least-squares fit)."""
    pb = lv_problem(times, clean, rtol=s["rtol"])
    ecfm = fit(pb, np.asarray(TRUTH) * 1.02, formulation="ecfm", sigma=sigma,
               options=FIT_OPTIONS).eps  # fmt: skip
    pb = lv_problem(times, clean, rtol=s["rtol"])
    return ecfm, fit(pb, ecfm, sigma=sigma, options=FIT_OPTIONS).eps


def _alarms(times, s, harvest, rng, bar):
    """Flagged, located and failed counts of the ECFM, flagged and failed of the
    random-force ECFM, over ``n_datasets`` draws; the last ECFM fit."""
    clean = simulate(times, harvest=harvest, window=s["window"])
    sigma = s["relative_noise"] * np.abs(clean)
    guess, guess_ls = _starts(times, clean, sigma, s)
    flagged = located = failed = r_flagged = r_failed = 0
    for _ in range(s["n_datasets"]):
        data = clean + sigma * rng.standard_normal(clean.shape)
        res = fit(lv_problem(times, data, rtol=s["rtol"]), guess, formulation="ecfm",
                  sigma=sigma, options=FIT_OPTIONS)  # fmt: skip
        failed += not res.success
        flagged += res.verdict.consistent is False
        located += _located(res, s["window"])
        rnd = fit(lv_problem(times, data, rtol=s["rtol"]), guess_ls,
                  formulation="ecfm-random", sigma=sigma, options=FIT_OPTIONS)  # fmt: skip
        r_failed += not rnd.success
        r_flagged += rnd.verdict.consistent is False
        bar.update()
    n = s["n_datasets"]
    return {"flagged": _rate(flagged, n), "located": _rate(located, n),
            "not_converged": _rate(failed, n), "random_flagged": _rate(r_flagged, n),
            "random_not_converged": _rate(r_failed, n)}, res  # fmt: skip


def _missing_term(s, rng, bar):
    times = _samplings(s)["monthly"]
    clean = simulate(times, eps=LOGISTIC_TRUTH, logistic=s["logistic_k"])
    sigma = s["missing_noise"] * np.abs(clean)
    pb = lv_problem(times, clean, rtol=s["rtol"], state_names=["u", "v"])
    guess = fit(pb, np.asarray(LOGISTIC_TRUTH) * 1.02, formulation="ecfm", sigma=sigma,
                options=FIT_OPTIONS).eps  # fmt: skip
    found = failed = 0
    coefs, extras = [], 0
    for _ in range(s["n_datasets"]):
        data = clean + sigma * rng.standard_normal(clean.shape)
        pb = lv_problem(times, data, rtol=s["rtol"], state_names=["u", "v"])
        res = fit(pb, guess, formulation="ecfm", sigma=sigma, options=FIT_OPTIONS)
        failed += not res.success
        terms = discover_terms(res)
        j = terms.names.index("u^2")
        c = float(terms.coef[j, 0])
        ok_u = (
            terms.selected[j, 0]
            and abs(c + s["logistic_k"]) <= s["coef_tolerance"] * s["logistic_k"]
        )
        allowed = np.zeros_like(terms.selected)
        for name in ("u", "u^2", "u*v"):
            allowed[terms.names.index(name), 0] = True
        extra = bool(np.any(terms.selected & ~allowed))
        extras += extra
        found += bool(ok_u)
        coefs.append(c)
        bar.update()
    n = s["n_datasets"]
    return {
        "found": _rate(found, n),
        "other_terms_selected": _rate(extras, n),
        "not_converged": _rate(failed, n),
        "u2_coef_median": float(np.median(coefs)),
        "u2_coef_quartiles": [float(q) for q in np.percentile(coefs, [25, 75])],
        "truth": -s["logistic_k"],
        "last_summary": terms.summary(),
    }


def run(settings, out_dir, progress):
    """Run the study and write its figure; returns the result dictionary."""
    s = settings
    rng = np.random.default_rng(s["seed"])
    result = {"settings": s, "correct": {}, "harvest": {}}
    n = s["n_datasets"]
    last = None
    with progress.bar(5 * n, "ode") as bar:
        for name, times in _samplings(s).items():
            out, _ = _alarms(times, s, 0.0, rng, bar)
            result["correct"][name] = out
            out, res = _alarms(times, s, s["harvest"], rng, bar)
            result["harvest"][name] = out
            last = res
        result["missing_term"] = _missing_term(s, rng, bar)
    _figure(last, s, out_dir)
    return result


def _figure(res, s, out_dir):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    res.forces.plot(ax=ax)
    ax.axvspan(*s["window"], color="0.85", zorder=0, label="harvest window")
    ax.set_title(f"monthly LV forces, harvest {s['harvest']:g} u left out (last data set)")
    ax.legend(fontsize=8)
    save_figure(fig, out_dir / "force_map.png")


def _fmt(r):
    return f"{r['rate']:.2f} [{r['ci95'][0]:.2f}, {r['ci95'][1]:.2f}] (R = {r['n']})"


def summary_rows(result):
    """Rows for ``summary.md``: false alarms, harvest flagged and located, term found.

    A false-alarm rate holds when its Clopper-Pearson 95 % interval meets the claimed
    range (at R = 30, 0 of 30 is likely at a true rate of 0.05: the point estimate alone
    would fail a right test); the other rates hold when the point estimate is >= 0.95.
    """
    rows = []
    for name in ("annual", "monthly"):
        for key, which in (("flagged", "ECFM"), ("random_flagged", "random-force ECFM")):
            fa = result["correct"][name][key]
            rows.append({
                "quantity": f"LV correct model, {name}: {which} false-alarm rate (alpha 0.05)",
                "paper": "0.01-0.10 (issue 36); holds: the 95 % interval meets it",
                "ours": _fmt(fa),
                "holds": fa["ci95"][0] <= ALARM_CLAIM[1] and fa["ci95"][1] >= ALARM_CLAIM[0],
            })  # fmt: skip
        h = result["harvest"][name]
        for key in ("flagged", "located", "random_flagged"):
            rows.append({
                "quantity": f"LV harvest window left out, {name}: {key.replace('_', ' ')}",
                "paper": ">= 0.95",
                "ours": _fmt(h[key]),
                "holds": h[key]["rate"] >= POWER_CLAIM,
            })  # fmt: skip
    m = result["missing_term"]
    rows.append({
        "quantity": "LV logistic term missing, monthly: discover_terms names u^2 (coef "
        "within 25 %)",
        "paper": ">= 0.95",
        "ours": f"{_fmt(m['found'])}, median coef {m['u2_coef_median']:.4f} "
        f"(truth {m['truth']:g})",
        "holds": m["found"]["rate"] >= POWER_CLAIM,
    })  # fmt: skip
    return rows
