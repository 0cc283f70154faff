"""``ecfm-uq reproduce all``: run every study and write ``summary.md``.

Data flows one way: the study registry (:mod:`ecfm_uq.studies`) <- this module <- the
command line (:mod:`ecfm_uq.cli`).

Each study runs with its default (paper) settings in its own folder; a failing study
does not stop the others, but makes the command fail with a one-line reason after the
summary (which records the failure) has been written.
"""

from __future__ import annotations

import time
from pathlib import Path

from .studies import (
    STUDY_NAMES,
    default_settings,
    load_study,
    missing_requirements,
    run_study,
)
from .studies._common import write_atomic


def _fmt_holds(h):
    return {True: "yes", False: "**no**", None: "n/a"}[h]


def render_summary(entries):
    """Markdown for a list of ``(name, rows, figures, error, seconds)`` entries."""
    lines = [
        "# ecfm_uq: paper vs measured",
        "",
        "Every study run with the paper's settings (see each `result.json` for the exact",
        "settings). *holds* says whether the paper's claim is reproduced.",
        "",
    ]
    for name, rows, figures, error, seconds in entries:
        lines += [f"## {name}", ""]
        if error is not None:
            lines += [error if error.startswith("skipped") else f"**FAILED**: {error}", ""]
            continue
        lines += [f"Result: [`{name}/result.json`]({name}/result.json), {seconds:.1f} s.", ""]
        lines += ["| quantity | paper | ours | holds |", "|---|---|---|---|"]
        for r in rows:
            lines.append(
                f"| {r['quantity']} | {r['paper']} | {r['ours']} | {_fmt_holds(r['holds'])} |"
            )
        if figures:
            lines += ["", "Figures: " + ", ".join(f"[{f.name}]({name}/{f.name})" for f in figures)]
        lines.append("")
    return "\n".join(lines) + "\n"


def reproduce_all(out, progress, seed=None, names=None):
    """Run every available study into ``out/<study>`` and write ``out/summary.md``.

    Raises
    ------
    RuntimeError
        After writing the summary, if any study failed (the message names them).
    """
    out = Path(out)
    names = list(STUDY_NAMES) if names is None else list(names)
    entries, failed = [], []
    with progress.bar(len(names), "studies") as bar:
        for name in names:
            progress.log(f"running {name} ...")
            t0 = time.perf_counter()
            missing = missing_requirements(name)
            if missing:  # an optional extra not installed: skipped, and said how to get it
                req, extra = missing[0]
                why = f'needs {req}: pip install -e ".[{extra}]"'
                entries.append((name, [], [], f"skipped ({why})", 0.0))
                progress.report(f"{name}: skipped, {why}")
                bar.update()
                continue
            try:
                settings = default_settings(name, out, seed)
                result = run_study(name, settings, out, progress)
                rows = load_study(name).summary_rows(result)
                figures = sorted((out / name).glob("*.png"))
                entries.append((name, rows, figures, None, time.perf_counter() - t0))
                progress.report(f"{name}: {entries[-1][-1]:.0f} s, results in {out / name}")
            except Exception as e:  # noqa: BLE001 - recorded, then re-raised as one failure
                msg = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
                entries.append((name, [], [], msg, time.perf_counter() - t0))
                failed.append(f"{name} ({msg})")
                progress.report(f"{name}: FAILED after {entries[-1][-1]:.0f} s: {msg}")
            bar.update()
    write_atomic(out / "summary.md", render_summary(entries))
    progress.report(f"wrote {out / 'summary.md'}")
    if failed:
        raise RuntimeError("studies failed: " + "; ".join(failed))
    return entries
