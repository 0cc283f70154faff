"""Study ``coverage``: are the reported 95 % intervals honest? (v0.2, issue 13)

Two models, R seeded synthetic data sets each, the standard and ECFM estimates fitted to
every one; the empirical coverage of their 95 % intervals (all parameters pooled) and
the mean interval width:

* ``steady``: the heated rod with unknown boundary data of paper Section 4
  (:func:`ecfm_uq.problems.heat.boundary_problem`, 9 sensors, two parameters), Gaussian
  sensor noise of known standard deviation; :func:`ecfm_uq.inverse.fit_steady` with the
  noise level given (``noise_model="known"``, the primary rows) and with it estimated
  from the residual (Student-t intervals, reported beside them).
* ``beam``: the random beam of paper Section 3.3, 25 replicates per data set, the
  standard and inner-outer (ECFM) pseudo-likelihood estimates of the load
  (:func:`ecfm_uq.inverse.fit_pseudo_likelihood`), intervals from the replicates.

The intervals come from the library's single uncertainty path
(:mod:`ecfm_uq.inverse.uncertainty`); this module only draws, counts and plots
(:mod:`ecfm_uq.inverse.coverage`).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..inverse.coverage import replicate_coverage, steady_coverage
from ..problems.beam import BeamModel
from ..problems.heat import boundary_problem
from ._common import pyplot, save_figure

NAME = "coverage"
DESCRIPTION = (
    "v0.2: empirical coverage of the 95 % intervals of the standard and ECFM estimates "
    "(steady rod with noisy sensors; random beam from replicates)"
)

DEFAULTS = {
    "seed": 0,
    "n_datasets": 200,
    "steady": {"true_eps": [1.0, -0.5], "n_basis": 20, "sensors": 9, "sigma": 0.01},
    "beam": {"true_eps": 1.0, "replicates": 25, "eps0": 0.5, "upper_bound_fraction": 0.99},
}
LEVEL = 0.95


def add_arguments(parser):
    d = DEFAULTS
    parser.add_argument(
        "--n-datasets",
        type=int,
        default=d["n_datasets"],
        help=f"synthetic data sets per model and formulation (default {d['n_datasets']})",
    )
    parser.add_argument(
        "--sigma",
        type=float,
        default=d["steady"]["sigma"],
        help=f"sensor noise of the steady model (default {d['steady']['sigma']})",
    )


def settings_from_args(args):
    if args.n_datasets < 2:
        raise ValueError(f"--n-datasets must be >= 2, got {args.n_datasets}")
    if not (np.isfinite(args.sigma) and args.sigma > 0):
        raise ValueError(f"--sigma must be a positive number, got {args.sigma}")
    steady = dict(DEFAULTS["steady"], sigma=float(args.sigma))
    return {
        "seed": DEFAULTS["seed"] if args.seed is None else int(args.seed),
        "n_datasets": int(args.n_datasets),
        "steady": steady,
        "beam": dict(DEFAULTS["beam"]),
        "level": LEVEL,
    }


def binomial_band(n, level=LEVEL, mass=0.95):
    """Central ``mass`` range of the coverage fraction of ``n`` honest intervals."""
    lo, hi = stats.binom.interval(mass, n, level)
    return float(lo / n), float(hi / n)


def run(settings, out_dir, progress):
    s = settings
    R, seed = s["n_datasets"], s["seed"]
    st = s["steady"]
    rod = boundary_problem(n_basis=st["n_basis"], sensors=st["sensors"])
    beam = BeamModel()
    bm = s["beam"]
    fit_options = {"bounds": [(0.0, bm["upper_bound_fraction"] * beam.beta_min)]}

    def sample(rng):
        return beam.sample_data(bm["true_eps"], bm["replicates"], rng=rng)

    result = {"n_datasets": R, "level": s["level"], "steady": {}, "beam": {}}
    with progress.bar(6 * R, "coverage") as bar:
        for key, form in (("standard", "standard"), ("ecfm", "ecfm")):
            for known, slot in ((True, key), (False, f"{key}_estimated_sigma")):
                result["steady"][slot] = steady_coverage(
                    rod.system, rod.M_obs, st["true_eps"], st["sigma"], R, seed, form,
                    known_sigma=known, callback=bar.update,
                )  # fmt: skip
        for key, form in (("standard", "standard"), ("ecfm", "inner-outer")):
            result["beam"][key] = replicate_coverage(
                beam.system, beam.M_obs, sample, [bm["true_eps"]], [bm["eps0"]], R, seed,
                form, fit_options=fit_options, callback=bar.update,
            )  # fmt: skip
    n_int = {m: result[m]["standard"]["n_intervals"] for m in ("steady", "beam")}
    result["binomial_band"] = {m: binomial_band(n) for m, n in n_int.items()}
    _figure(result, out_dir)
    return result


def _figure(result, out_dir):
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.8))
    rows = [
        ("steady", "standard", "rod, standard"),
        ("steady", "ecfm", "rod, ECFM"),
        ("steady", "standard_estimated_sigma", "rod, standard, s est."),
        ("steady", "ecfm_estimated_sigma", "rod, ECFM, s est."),
        ("beam", "standard", "beam, standard"),
        ("beam", "ecfm", "beam, ECFM"),
    ]
    y = np.arange(len(rows))[::-1]
    for yi, (model, key, label) in zip(y, rows, strict=True):
        r = result[model][key]
        lo, hi = result["binomial_band"][model]
        ax.plot([lo, hi], [yi, yi], color="0.75", lw=6, solid_capstyle="butt")
        ax.plot(r["coverage"], yi, "o", color="C1" if "ECFM" in label else "C0")
        bx.barh(yi, r["mean_width"], color="C1" if "ECFM" in label else "C0")
    ax.axvline(result["level"], color="k", lw=0.8, ls="--")
    ax.set_yticks(y, [r[2] for r in rows])
    ax.set_xlabel("empirical coverage of the 95 % intervals")
    ax.set_title(f"{result['n_datasets']} data sets; grey: 95 % binomial band of honesty")
    bx.set_yticks(y, [])
    bx.set_xscale("log")
    from matplotlib.ticker import NullFormatter

    bx.xaxis.set_minor_formatter(NullFormatter())
    bx.set_xlabel("mean interval width (each model in its parameters' units)")
    bx.set_title("how wide: ECFM pays for its robustness")
    fig.tight_layout()
    save_figure(fig, out_dir / "coverage.png")


def summary_rows(result):
    rows = []
    for model, label in (("steady", "rod (Sec. 4), known sigma"), ("beam", "beam (Sec. 3.3)")):
        lo, hi = result["binomial_band"][model]
        for key, name in (("standard", "standard"), ("ecfm", "ECFM")):
            r = result[model][key]
            rows.append(
                {
                    "quantity": f"coverage/{model}: {name} 95 % intervals, {label}",
                    "paper": "not in the paper (v0.2): 0.92-0.98",
                    "ours": f"{r['coverage']:.3f} (width {r['mean_width']:.3g}; "
                    f"binomial band {lo:.3f}-{hi:.3f})",
                    "holds": 0.92 <= r["coverage"] <= 0.98,
                }
            )
    for key, name in (("standard", "standard"), ("ecfm", "ECFM")):
        r = result["steady"][f"{key}_estimated_sigma"]
        rows.append(
            {
                "quantity": f"coverage/steady: {name}, sigma estimated from the residual",
                "paper": "reported, not required",
                "ours": f"{r['coverage']:.3f} (width {r['mean_width']:.3g})",
                "holds": None,
            }
        )
    return rows
