"""The printed table of a fit (:meth:`~ecfm_uq.inverse.InverseResult.summary`)."""

from __future__ import annotations

import numpy as np

from ..._validation import check_level

__all__ = ["summary_table"]


def _interval(result, level, j, prof):
    """(lo, hi, label) of parameter ``j``: the profile interval of ``prof`` (a profile
    summary at ``level``) where it has one, else the delta-method one."""
    if (
        prof is not None
        and abs(prof.level - level) < 1e-12
        and np.all(np.isfinite(prof.intervals[j]) | np.isinf(prof.intervals[j]))
        and not np.any(np.isnan(prof.intervals[j]))
    ):
        return prof.intervals[j][0], prof.intervals[j][1], "profile"
    unc = result.uncertainty
    if unc is None or unc.stderr is None:
        return np.nan, np.nan, ""
    k = unc.quantile(level)
    se = unc.stderr[j]
    return (
        result.eps[j] - k * se,
        result.eps[j] + k * se,
        "delta" + (f", t({unc.dof})" if unc.dof is not None else ""),
    )


def _num(x):
    return f"{x:.6g}" if np.isfinite(x) else ("-inf" if x < 0 else "inf" if x > 0 else "n/a")


def summary_table(result, level=0.95, profile=None):
    """The fit as text: one row per parameter, then status, optimality and verdict;
    ``profile``: a profile summary whose intervals to show (else the delta method's)."""
    level = check_level("level", level)
    if profile is not None and not hasattr(profile, "intervals"):
        raise TypeError(
            f"`profile` must be the ProfileSummary of profile_likelihood(result, level), got "
            f"{type(profile).__name__}"
        )
    estimate = getattr(profile, "estimate", None)
    if estimate is not None and (
        np.shape(estimate) != np.shape(result.eps)
        or not np.allclose(estimate, result.eps, rtol=1e-12, atol=0.0)
    ):
        raise ValueError(
            f"`profile` was computed for another fit (estimate {np.round(estimate, 6).tolist()}"
            f", this fit's is {np.round(result.eps, 6).tolist()}): pass "
            "profile_likelihood(result) of this result"
        )
    if profile is not None and abs(profile.level - level) > 1e-12:
        raise ValueError(
            f"`profile` was computed at level {profile.level:g}, the table is at {level:g}: "
            "pass profile_likelihood(result, level) at the table's level"
        )
    n = result.eps.size
    names = getattr(result, "names", None) or [f"eps[{j}]" for j in range(n)]
    unc = result.uncertainty
    se = unc.stderr if unc is not None and unc.stderr is not None else np.full(n, np.nan)
    pct = f"{100 * level:g} %"
    rows = [("parameter", "estimate", "std err", f"{pct} interval", "kind")]
    for j in range(n):
        lo, hi, kind = _interval(result, level, j, profile)
        rows.append((names[j], _num(result.eps[j]), _num(se[j]), f"[{_num(lo)}, {_num(hi)}]", kind))
    widths = [max(len(r[c]) for r in rows) for c in range(5)]
    lines = [f"{result.formulation or 'fit'} fit ({result.method or 'optimizer'})"]
    rule = "-" * (sum(widths) + 8)
    lines.append(rule)
    for k, r in enumerate(rows):
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
        if k == 0:
            lines.append(rule)
    lines.append(rule)
    opt = "" if result.optimality is None else f", optimality {result.optimality:.2e}"
    lines.append(f"status: {result.status.name}{opt}; {result.nfev} model evaluations")
    missing = result.extra.get("n_missing")
    if missing:
        lines.append(f"data: {missing} missing reading(s) (NaN) skipped")
    if unc is not None and not unc.success and unc.message:
        lines.append(f"uncertainty: {unc.message}")
    elif unc is not None and unc.success:
        noise = {"known": "sigma given", "estimated": "sigma estimated from the residual"}
        lines.append(f"uncertainty: {unc.method}, {noise.get(unc.noise_model, unc.noise_model)}")
    v = result.verdict
    if v is not None:
        head = {True: "consistent", False: "NOT consistent", None: "no test"}[v.consistent]
        test = "" if v.p_value is None else f" ({v.test}, p = {v.p_value:.3g}, alpha = {v.alpha:g})"
        lines.append(f"verdict: {head}{test}")
        lines.append(f"  {v.message}")
    return "\n".join(lines)
