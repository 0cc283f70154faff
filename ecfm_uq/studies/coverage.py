"""``ecfm-uq reproduce coverage``: are the reported 95 % intervals honest? (issue 13)

Every fit reports a delta-method covariance of its estimate
(:mod:`ecfm_uq.inverse.statistics.uncertainty`). This study draws R seeded synthetic data sets from
two models at known parameters, fits each by the standard and the ECFM formulation, and
counts how often the reported 95 % intervals contain the truth
(:mod:`ecfm_uq.inverse.coverage`):

* ``steady``: the paper's heat rod with unknown boundary data (Section 4,
  :func:`ecfm_uq.problems.heat.boundary_problem`), 7 sensors, Gaussian sensor noise of
  known standard deviation (:func:`~ecfm_uq.inverse.fit` with ``sigma``); the
  same with sigma estimated from the residual is recorded as ``steady_estimated_sigma``;
* ``beam``: the stochastic beam of Section 3.3 (:class:`ecfm_uq.problems.beam.BeamModel`)
  from D replicated measurements, standard and ECFM inner-outer pseudo-likelihood
  estimates (:func:`~ecfm_uq.inverse.fit` of replicated data), covariance from the
  replicates;
* ``operator`` (issue 20): the reaction rod (:class:`ecfm_uq.problems.reaction.ReactionRod`),
  its reaction rate inside the operator, 4 sensors, 2 % noise: delta-method against
  profile-likelihood intervals, per parameter, for the standard fit and the random-force
  ECFM, with one variance for every force and with a variance per force (the sparse prior)
  (:func:`~ecfm_uq.inverse.coverage.interval_coverage`);
* ``discrepancy`` (issue 20): size and power of the test of tau = 0 against a narrow source
  missing from the rod, by amplitude, for both force priors
  (:func:`~ecfm_uq.inverse.coverage.discrepancy_power`).

The existing ``steady`` ECFM rows use the paper's exact-match forces
(``formulation="ecfm"``), so their numbers are those of v0.2.

This module only reads settings, calls the library and draws the figure.
"""

from __future__ import annotations

import numpy as np

from ..inverse import ModelProblem
from ..inverse.coverage import (
    binomial_band,
    discrepancy_power,
    interval_coverage,
    likelihood_coverage,
    model_coverage,
    steady_coverage,
)
from ..inverse.problems.galerkin import SteadyProblem
from ..plotting import pyplot, save_figure
from ..problems import regression
from ..problems.beam import BeamModel
from ..problems.heat import boundary_problem
from ..problems.reaction import ReactionRod

NAME = "coverage"
DESCRIPTION = (
    "Issue 13: empirical coverage and width of the 95% intervals of the standard and ECFM "
    "estimates over seeded synthetic data sets (steady heat rod, stochastic beam)"
)

BAND = (0.92, 0.98)  # the acceptance band for 200 data sets

DEFAULTS = {
    "seed": 0,
    "n_datasets": 200,
    # the blocks whose fits cost seconds each (the beam's pseudo-likelihood, the
    # random-force ECFM's operator rows with their profiles and its discrepancy test):
    # ~7 s per data set together until the random-force ECFM had its exact gradient
    # (2026-11-26: 30 by default, the study 370-377 s in a fresh clone), ~2 s since: with
    # 100 the study took 267 s (264 s CPU; 2026-11-27, one worker on a shared machine),
    # with 200 475 s CPU, too long for `reproduce all` within ten minutes; 200 on request
    "n_datasets_slow": 200,
    "steady": {
        "n_basis": 20,
        "sensors": 7,
        "true_eps": [1.0, 0.5],
        "sigma": 0.04,  # 2 % of the largest noise-free reading (1.93)
    },
    "beam": {
        "true_eps": 1.0,
        "replicates": 25,
        "eps0": 0.5,
        "order": 5,
        "n_basis": 6,
        "sensors": [0.2, 0.4, 0.6, 0.8, 1.0],
        "eps_upper_bound_fraction": 0.99,
        "solve_tol": 1e-10,
    },
    "operator": {
        "sensors": 4,
        "true_eps": [0.5, 20.0],
        "relative_noise": 0.02,  # sigma as a fraction of the mean noise-free reading
    },
    "function": {  # a model that is a Python function (issue 28)
        "n_points": 12,
        "x_max": 5.0,
        "true_eps": [2.0, 0.7, 0.3],  # a exp(-b x) + c
        "sigma": 0.05,  # small samples: sigma estimated, profile-t intervals
        "verdict_sigma": 0.02,  # the offset c = 0.3 is 15 sigma: missing it is flagged
        "offset_bounds": [0.3, 1.0],  # the truth on the bound: estimates reach it
        "mirror_points": 7,
        "mirror_true_eps": [2.0, 0.8],  # a exp(-b^2 x): b and -b, two basins
        "mirror_bounds": [[0.1, 5.0], [-2.0, 2.0]],
        "mirror_eps0": [1.0, -0.3],  # fits land in the mirror basin
        "relative_noise": 0.02,
    },
    "discrepancy": {
        "sensors": 6,
        "true_eps": [1.5, 20.0],
        "relative_noise": 0.02,
        "source_at": 0.62,
        "amplitudes": [0.0, 8.0, 16.0, 24.0],
        "alpha": 0.05,
    },
}
WIDTH_RATIO_LIMIT = 1.5  # the issue: ECFM intervals no wider than 1.5x the standard ones
SIZE_BAND = (0.02, 0.08)  # false alarms at alpha = 0.05 the issue accepts
PROFILE_T_BAND = (0.93, 0.97)  # issue 28: profile-t coverage with few data
REGIONS_BAND = (0.92, 0.99)  # issue 28: profile regions on a two-basin likelihood

# the operator block's fits: name -> (formulation, options); ecfm_sparse is the random-force
# ECFM with a variance per force (options={"force_prior": "sparse"})
OPERATOR_FITS = {
    "standard": ("standard", None),
    "ecfm": ("ecfm-random", None),
    "ecfm_sparse": ("ecfm-random", {"force_prior": "sparse"}),
}

CASES = (
    ("steady", "standard", "standard"),
    ("steady", "ecfm", "ecfm"),
    ("beam", "standard", "standard"),
    ("beam", "ecfm", "inner-outer"),
)


def add_arguments(parser):
    """Study options (``ecfm-uq reproduce coverage --help``)."""
    parser.add_argument(
        "--n-datasets",
        type=int,
        default=DEFAULTS["n_datasets"],
        help=f"synthetic data sets R per model (default {DEFAULTS['n_datasets']})",
    )
    parser.add_argument(
        "--n-datasets-slow",
        type=int,
        default=DEFAULTS["n_datasets_slow"],
        help="synthetic data sets of the beam and random-force ECFM blocks (default "
        f"{DEFAULTS['n_datasets_slow']}; 200 reproduces the v0.3 rows: ~2 s per data set)",
    )
    parser.add_argument(
        "--sigma",
        type=float,
        default=DEFAULTS["steady"]["sigma"],
        help=f"sensor noise standard deviation of the steady model "
        f"(default {DEFAULTS['steady']['sigma']:g})",
    )
    parser.add_argument(
        "--replicates",
        type=int,
        default=DEFAULTS["beam"]["replicates"],
        help=f"beam replicates D per sensor (default {DEFAULTS['beam']['replicates']})",
    )


def settings_from_args(args):
    """Validate the options and return the settings recorded in ``result.json``."""
    s = {
        "seed": DEFAULTS["seed"] if args.seed is None else int(args.seed),
        "n_datasets": int(args.n_datasets),
        "n_datasets_slow": int(args.n_datasets_slow),
        "steady": dict(DEFAULTS["steady"]),
        "beam": dict(DEFAULTS["beam"]),
        "operator": dict(DEFAULTS["operator"]),
        "function": dict(DEFAULTS["function"]),
        "discrepancy": dict(DEFAULTS["discrepancy"]),
    }
    if s["seed"] < 0:
        raise ValueError(f"--seed must be non-negative, got {s['seed']}")
    if s["n_datasets"] < 1:
        raise ValueError(f"--n-datasets must be >= 1, got {s['n_datasets']}")
    if s["n_datasets_slow"] < 1:
        raise ValueError(f"--n-datasets-slow must be >= 1, got {s['n_datasets_slow']}")
    if not (np.isfinite(args.sigma) and args.sigma > 0):
        raise ValueError(f"--sigma must be a positive noise standard deviation, got {args.sigma}")
    s["steady"]["sigma"] = float(args.sigma)
    if args.replicates < 3:
        raise ValueError(
            f"--replicates must be >= 3 (a sample covariance with D - 1 >= 2 dof), "
            f"got {args.replicates}"
        )
    s["beam"]["replicates"] = int(args.replicates)
    return s


def _block(r):
    """JSON block of one coverage run (per-data-set arrays kept for the figure only)."""
    keys = ("coverage", "mean_width", "n_failed", "n_intervals", "coverage_per_parameter")
    out = {k: r[k] for k in keys if k in r}
    out["band"] = binomial_band(r["n_intervals"])
    return out


def run(settings, out_dir, progress):
    """Run the study and write its figure; returns the result dictionary."""
    s = settings
    R, R_slow, seed = s["n_datasets"], s["n_datasets_slow"], s["seed"]
    st, bm = s["steady"], s["beam"]
    heat = boundary_problem(n_basis=st["n_basis"], sensors=st["sensors"])
    beam = BeamModel(n_basis=bm["n_basis"], order=bm["order"], sensors=bm["sensors"])
    beam_fit = {
        "bounds": [(0.0, bm["eps_upper_bound_fraction"] * beam.beta_min)],
        "problem_options": {"solve_tol": bm["solve_tol"]},
    }

    def sample(gen):
        return beam.sample_data(bm["true_eps"], bm["replicates"], rng=gen)

    raw = {}
    with progress.bar(10, "coverage") as bar:
        for form in ("standard", "ecfm"):
            for known in (True, False):
                key = ("steady" if known else "steady_estimated_sigma", form)
                raw[key] = steady_coverage(
                    heat.system,
                    heat.M_obs,
                    st["true_eps"],
                    st["sigma"],
                    R,
                    seed,
                    form,
                    known_sigma=known,
                )
            bar.update()
        for form, lik in (("standard", "standard"), ("ecfm", "inner-outer")):
            progress.log(f"coverage: beam {form}")
            raw[("beam", form)] = likelihood_coverage(
                beam.system,
                beam.M_obs,
                sample,
                [bm["true_eps"]],
                [bm["eps0"]],
                R_slow,
                seed,
                lik,
                **beam_fit,
            )
            bar.update()
        function = _function(s["function"], R, seed)
        operator = _operator(s["operator"], {"standard": R}, R_slow, seed, bar)
        discrepancy = _discrepancy(s["discrepancy"], R_slow, seed)
        bar.update()

    result = {"settings": s, "n_datasets": R, "n_datasets_slow": R_slow, "band": list(BAND)}
    result["operator"] = operator
    result["function"] = function
    result["discrepancy"] = discrepancy
    for (model, form), r in raw.items():
        result.setdefault(model, {})[form] = _block(r)
    result["steady"]["noise_model"] = "known sigma"
    result["steady_estimated_sigma"]["noise_model"] = "sigma estimated from the residual, Student-t"
    result["beam"]["noise_model"] = "sample covariance of the replicates, Student-t (D - 1)"
    # what the intervals claim against what the estimates do: the beam's single
    # parameter, empirical spread of the estimate vs the mean reported standard error
    for form in ("standard", "ecfm"):
        r = raw[("beam", form)]
        if r["n_intervals"]:
            result["beam"][form]["estimate_std"] = float(np.std(r["eps"][:, 0], ddof=1))
            result["beam"][form]["mean_stderr"] = float(np.mean(r["stderr"][:, 0]))
    _figure(result, raw, out_dir)
    _operator_figure(result, out_dir)
    return result


def _operator(st, sizes, R_other, seed, bar):
    """Delta-method vs profile-likelihood coverage on the reaction rod."""
    rod = ReactionRod(st["sensors"])
    clean = rod.data(st["true_eps"])
    sigma = st["relative_noise"] * float(np.abs(clean).mean())
    problem = SteadyProblem(rod.system, rod.M_obs, clean)
    out = {"sigma": sigma}
    for form, (formulation, options) in OPERATOR_FITS.items():
        R = sizes.get(form, R_other)
        r = interval_coverage(problem, clean, st["true_eps"], sigma, R, seed, formulation,
                              options=options)  # fmt: skip
        out[form] = {
            "n_failed": r["n_failed"],
            "n_not_consistent": r["n_not_consistent"],
            "n_at_bound": 0,  # no bounds are given: an estimate cannot sit at one
            "band": binomial_band(R),  # of the profile intervals (every data set)
            "n_datasets": R,
        }
        for kind in ("delta", "profile"):
            # an open (infinite) median width is recorded as None
            out[form][kind] = {
                k: [float(x) if np.isfinite(x) else None for x in np.asarray(v)]
                for k, v in r[kind].items()
            }
        bar.update()
    std = out["standard"]["profile"]["median_width_per_parameter"]
    for form in ("ecfm", "ecfm_sparse"):
        ecfm = out[form]["profile"]["median_width_per_parameter"]
        out[f"{form}_over_standard_profile_width"] = [
            None if a is None or b is None else a / b for a, b in zip(ecfm, std, strict=True)
        ]
    return out


def _function(st, R, seed):
    """Models that are Python functions: profile-t coverage with few data and sigma
    estimated, the verdict's size without and with sigma (and with estimates at a bound),
    its power against a missing offset, and profile regions on a likelihood with two
    basins."""
    x = np.linspace(0.0, st["x_max"], st["n_points"])
    truth = np.array(st["true_eps"])
    full = regression.decay_with_offset(x)
    clean = full(truth)
    problem = ModelProblem(full, clean)
    out = {}
    out["small_sample"] = model_coverage(problem, clean, truth, st["sigma"], R, seed,
                                         known_sigma=False)  # fmt: skip
    s = st["verdict_sigma"]
    out["no_sigma"] = model_coverage(problem, clean, truth, s, R, seed, known_sigma=False,
                                     profile=False)  # fmt: skip
    out["sigma"] = model_coverage(problem, clean, truth, s, R, seed, profile=False)
    bounds = [(None, None), (None, None), tuple(st["offset_bounds"])]
    out["sigma_bounded"] = model_coverage(problem, clean, truth, s, R, seed, bounds=bounds,
                                          profile=False)  # fmt: skip
    missing = ModelProblem(regression.decay(x), clean)
    out["missing_offset"] = model_coverage(missing, clean, truth[:2], s, R, seed,
                                           profile=False)  # fmt: skip
    xm = np.linspace(0.1, 3.0, st["mirror_points"])
    mirror = regression.mirror_decay(xm)
    mtruth = np.array(st["mirror_true_eps"])
    mclean = mirror(mtruth)
    sm = st["relative_noise"] * float(np.abs(mclean).mean())
    out["two_basins"] = model_coverage(
        ModelProblem(mirror, mclean), mclean, mtruth, sm, R, seed, eps0=st["mirror_eps0"],
        bounds=[tuple(b) for b in st["mirror_bounds"]],
    )  # fmt: skip
    return {
        k: {
            key: (val if not isinstance(val, dict) else
                  {kk: [float(c) for c in np.atleast_1d(vv)] for kk, vv in val.items()})
            for key, val in r.items()
        }
        for k, r in out.items()
    }  # fmt: skip


def _discrepancy(st, R, seed):
    """Size and power of the random-force ECFM's test of tau = 0 on the reaction rod, with
    each force prior."""
    rod = ReactionRod(st["sensors"])
    clean = rod.data(st["true_eps"])
    sigma = st["relative_noise"] * float(np.abs(clean).mean())
    problem = SteadyProblem(rod.system, rod.M_obs, clean)
    by_amp = {a: rod.data(st["true_eps"], a, st["source_at"]) for a in st["amplitudes"]}
    out = {"sigma": sigma, "size_band": list(SIZE_BAND)}
    # the same data sets fitted with each force prior (the test is the same statistic, at
    # each prior's estimate)
    for key, options in (("rows", None), ("rows_sparse", {"force_prior": "sparse"})):
        out[key] = discrepancy_power(
            problem, by_amp, sigma, st["true_eps"], R, seed, st["alpha"], options
        )
    return out


def _operator_figure(result, out_dir):
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    op = result["operator"]
    labels, x = [], 0
    for form in OPERATOR_FITS:
        for kind, marker in (("delta", "s"), ("profile", "o")):
            cov = op[form][kind]["coverage_per_parameter"]
            a.plot([x, x + 0.25], cov, marker, color="C0" if kind == "delta" else "C1", ms=8)
            labels.append((x + 0.125, f"{form}\n{kind}"))
            x += 1
    a.axhline(0.95, color="k", lw=1)
    a.axhspan(*result["band"], color="C2", alpha=0.08)
    a.set_xticks([p for p, _ in labels], [t for _, t in labels], fontsize=8)
    a.set_ylabel("coverage of 95 % intervals (eps0, eps1)")
    a.set_title(f"reaction rod, parameter in the operator ({result['n_datasets']} data sets)")
    rows = result["discrepancy"]["rows"]
    rms = [r["residual_rms_over_sigma"] for r in rows]
    b.plot(rms, [r["tau_test_rejects"] for r in rows], "o-", label="random-force test of tau = 0")
    sparse = result["discrepancy"].get("rows_sparse", [])
    if sparse:
        b.plot(rms, [r["tau_test_rejects"] for r in sparse], "^:",
               label="the same, sparse force prior's estimate")  # fmt: skip
    b.plot(rms, [r["chi2_rejects"] for r in rows], "s--", label="chi2 test of the standard fit")
    b.axhline(result["settings"]["discrepancy"]["alpha"], color="k", lw=0.8, ls=":")
    b.axhline(0.8, color="C2", lw=0.8, ls=":")
    b.set_xlabel("standard fit's residual rms / sigma (missing source amplitude grows)")
    b.set_ylabel("fraction of data sets flagged")
    b.set_title("can the model explain the data? size and power")
    b.legend(fontsize=7)
    save_figure(fig, out_dir / "operator.png")


def _figure(result, raw, out_dir):
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    labels, cov, width, band = [], [], [], []
    rows = [("steady", f) for f in ("standard", "ecfm")]
    rows += [("steady_estimated_sigma", f) for f in ("standard", "ecfm")]
    rows += [("beam", f) for f in ("standard", "ecfm")]
    names = {"steady": "steady", "steady_estimated_sigma": "steady\nσ est.", "beam": "beam"}
    for model, form in rows:
        blk = result[model][form]
        labels.append(f"{names[model]}\n{form}")
        cov.append(blk["coverage"])
        width.append(blk["mean_width"])
        band.append(blk["band"])
    x = np.arange(len(labels))
    band = np.array(band)
    a.bar(
        x,
        band[:, 1] - band[:, 0],
        bottom=band[:, 0],
        width=0.6,
        color="0.85",
        label="binomial 95 % band of honest intervals",
    )
    a.plot(x, cov, "o", color="C0", ms=8, label="empirical coverage")
    a.axhline(0.95, color="k", lw=1, label="nominal 0.95")
    a.axhspan(*result["band"], color="C2", alpha=0.08, label=f"accepted {result['band']}")
    a.set_xticks(x, labels, fontsize=7)
    a.set_ylim(min(0.85, min(cov) - 0.02), 1.005)
    a.set_ylabel("fraction of 95 % intervals holding the truth")
    a.set_title(f"coverage over {result['n_datasets']} data sets per model")
    a.legend(fontsize=7, loc="lower left")
    b.bar(x, width, width=0.6, color=["C0", "C1"] * 3)
    b.set_yscale("log")
    b.set_xticks(x, labels, fontsize=7)
    b.set_ylabel("mean width of the 95 % interval")
    b.set_title("interval widths (standard C0, ECFM C1)")
    save_figure(fig, out_dir / "coverage.png")


def summary_rows(result):
    """Rows for ``summary.md``: coverage in the band, and the interval widths."""
    R = result["n_datasets"]
    rows = []
    R_slow = result.get("n_datasets_slow", R)
    for model, label in (
        ("steady", "steady heat rod, known sigma"),
        ("beam", "beam, pseudo-likelihood, replicates"),
        ("steady_estimated_sigma", "steady heat rod, sigma estimated"),
    ):
        n = R_slow if model == "beam" else R
        lo, hi = coverage_band(n)
        for form in ("standard", "ecfm"):
            blk = result[model][form]
            check = model != "steady_estimated_sigma"
            rows.append(
                {
                    "quantity": f"coverage of 95 % intervals, {label}, {form} ({n} data sets)",
                    "paper": f"in [{lo:.3g}, {hi:.3g}]" if check else "not claimed",
                    "ours": f"{blk['coverage']:.4f} (mean width {blk['mean_width']:.3g}, "
                    f"{blk['n_failed']} failed)",
                    "holds": (lo <= blk["coverage"] <= hi) if check else None,
                }
            )
    op = result["operator"]
    for form in OPERATOR_FITS:
        n = op[form].get("n_datasets", R)
        lo, hi = coverage_band(n)
        for kind in ("delta", "profile"):
            cov = op[form][kind]["coverage_per_parameter"]
            rows.append(
                {
                    "quantity": f"coverage per parameter, reaction rod (parameter in the "
                    f"operator), {form}, {kind} intervals ({n} data sets)",
                    "paper": f"in [{lo:.3g}, {hi:.3g}]" if kind == "profile" else "not claimed",
                    "ours": ", ".join(f"{c:.3f}" for c in cov),
                    "holds": all(lo <= c <= hi for c in cov) if kind == "profile" else None,
                }
            )
    for form, what in (("ecfm", ""), ("ecfm_sparse", " (sparse force prior)")):
        ratio = op[f"{form}_over_standard_profile_width"]
        rows.append(
            {
                "quantity": f"median profile-interval width, random-force ECFM{what} / standard",
                "paper": f"<= {WIDTH_RATIO_LIMIT}",
                # None: the median interval is open for both (the data do not bound it)
                "ours": ", ".join("open in both" if r is None else f"{r:.3f}" for r in ratio),
                "holds": all(r <= WIDTH_RATIO_LIMIT for r in ratio if r is not None),
            }
        )
    rows += _function_rows(result.get("function"), R)
    disc = result["discrepancy"]
    pairs = [(row, "") for row in disc["rows"]]
    pairs += [(row, ", sparse force prior") for row in disc.get("rows_sparse", [])]
    size_lo, size_hi = size_band(R_slow)
    for row, what in pairs:
        size = row["amplitude"] == 0.0
        rows.append(
            {
                "quantity": f"discrepancy test (tau = 0{what}) rejects, missing source amplitude "
                f"{row['amplitude']:g} (standard residual {row['residual_rms_over_sigma']:.2f} "
                "sigma)",
                "paper": f"in [{size_lo:.3g}, {size_hi:.3g}] ({R_slow} data sets)" if size else (
                    ">= 0.8" if row["residual_rms_over_sigma"] >= 3.0 else "not claimed"
                ),
                "ours": f"{row['tau_test_rejects']:.3f} (chi2 test: {row['chi2_rejects']:.3f})",
                "holds": (size_lo <= row["tau_test_rejects"] <= size_hi) if size else (
                    row["tau_test_rejects"] >= 0.8
                    if row["residual_rms_over_sigma"] >= 3.0 else None
                ),
            }
        )  # fmt: skip
    return rows


def coverage_band(n):
    """Where the coverage of honest 95 % intervals lies: the issue's band at 200 data sets
    or more, the binomial 95 % range of the hits below (fewer data sets say less)."""
    return BAND if n >= 200 else binomial_band(n)


def size_band(n, alpha=0.05):
    """Where a test of size ``alpha`` rejects: the issue's band at 200 data sets or more,
    the binomial 95 % range of the rejections below."""
    return SIZE_BAND if n >= 200 else binomial_band(n, alpha)


def _function_rows(fn, R):
    """Rows of the function-model block (absent from results written before v0.4)."""
    if fn is None:
        return []
    lo, hi = PROFILE_T_BAND
    rows = []
    cov = fn["small_sample"]["regions"]["coverage_per_parameter"]
    rows.append(
        {
            "quantity": f"profile-t intervals, sigma estimated, 12 data, 3 parameters, coverage "
            f"per parameter ({R} data sets)",
            "paper": f"in [{lo}, {hi}]",
            "ours": ", ".join(f"{c:.3f}" for c in cov),
            "holds": all(lo <= c <= hi for c in cov),
        }
    )
    cov = fn["two_basins"]["regions"]["coverage_per_parameter"]
    rows.append(
        {
            "quantity": "profile regions, a likelihood with two basins (fits land in the other), "
            f"coverage per parameter ({R} data sets)",
            "paper": f"in {list(REGIONS_BAND)}",
            "ours": ", ".join(f"{c:.3f}" for c in cov),
            "holds": all(REGIONS_BAND[0] <= c <= REGIONS_BAND[1] for c in cov),
        }
    )
    none = fn["no_sigma"]
    rows.append(
        {
            "quantity": f"verdict without sigma on consistent data: 'inconsistent' ({R} data sets)",
            "paper": "never",
            "ours": f"{none['n_not_consistent']} (no test: {none['n_no_test']})",
            "holds": none["n_not_consistent"] == 0,
        }
    )
    for key, what in (("sigma", ""), ("sigma_bounded", ", offset bounded at its true value")):
        r = fn[key]
        rate = r["n_not_consistent"] / r["n_datasets"]
        rows.append(
            {
                "quantity": f"chi2 verdict's false alarms at alpha = 0.05{what} ({R} data sets; "
                f"{r['n_at_bound']} estimates at a bound)",
                "paper": f"in {SIZE_BAND}",
                "ours": f"{rate:.3f}",
                "holds": SIZE_BAND[0] <= rate <= SIZE_BAND[1],
            }
        )
    r = fn["missing_offset"]
    rate = r["n_not_consistent"] / r["n_datasets"]
    rows.append(
        {
            "quantity": "chi2 verdict, a model missing the offset (15 sigma): flagged",
            "paper": ">= 0.99",
            "ours": f"{rate:.3f}",
            "holds": rate >= 0.99,
        }
    )
    return rows  # fmt: skip
