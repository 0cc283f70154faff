"""``ecfm-uq reproduce all``: run every study and write ``summary.md``.

Data flows one way: the study registry (:mod:`ecfm_uq.studies`) <- this module <- the
command line (:mod:`ecfm_uq.cli`).

Each study runs with its default (paper) settings in its own folder; a failing study
does not stop the others, but makes the command fail with a one-line reason after the
summary (which records the failure) has been written.
"""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from threadpoolctl import threadpool_limits

from .studies import (
    STUDY_NAMES,
    default_settings,
    load_study,
    missing_requirements,
    run_study,
)
from .studies._common import QUIET, write_atomic


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


#: the studies of ``all`` that run longest, started first when ``workers > 1`` (the rest
#: fill the worker that frees first); measured in a fresh clone on 2 cores: ode 432 s at
#: R = 100, coverage 490 s with every row at R = 200, the rest ~1 min together (8 min 13 s)
LONGEST_FIRST = ("ode", "coverage")


def _run_entry(name, out, seed, progress):
    """Run study ``name`` for ``all``: its summary entry ``(name, rows, figures, error,
    seconds)``, the line to report, and whether it failed."""
    t0 = time.perf_counter()
    try:
        missing = missing_requirements(name)
        if missing:  # an optional extra not installed: skipped, and said how to get it
            req, extra = missing[0]
            why = f'needs {req}: pip install -e ".[{extra}]"'
            return (name, [], [], f"skipped ({why})", 0.0), f"{name}: skipped, {why}", None
        settings = default_settings(name, out, seed)
        result = run_study(name, settings, out, progress)
        rows = load_study(name).summary_rows(result)
        figures = sorted((out / name).glob("*.png"))
        seconds = time.perf_counter() - t0
        return (
            (name, rows, figures, None, seconds),
            (f"{name}: {seconds:.0f} s, results in {out / name}"),
            None,
        )
    except Exception as e:  # noqa: BLE001 - recorded, then re-raised as one failure
        msg = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        seconds = time.perf_counter() - t0
        return (
            (name, [], [], msg, seconds),
            (f"{name}: FAILED after {seconds:.0f} s: {msg}"),
            f"{name} ({msg})",
        )


def _worker_init():
    # each worker single-threaded, as the command line is (cli.main): two workers on two
    # cores, not two times the BLAS threads
    threadpool_limits(limits=1, user_api="blas")


def _run_in_worker(name, out, seed):
    return _run_entry(name, out, seed, QUIET)


def reproduce_all(out, progress, seed=None, names=None, workers=1):
    """Run every available study into ``out/<study>`` and write ``out/summary.md``.

    Parameters
    ----------
    out : path
        The output folder.
    progress : Progress
        Where the per-study lines go.
    seed : int, optional
        Every study's seed (its default if omitted).
    names : list of str, optional
        The studies (default :data:`~ecfm_uq.studies.STUDY_NAMES`).
    workers : int, optional
        Studies run at once, each in its own single-threaded process (the longest, in
        :data:`LONGEST_FIRST`, started first). The lines, ``summary.md`` and every
        ``result.json`` are the same as with 1 (the default: in this process), in the
        order of ``names``; only the seconds differ.

    Raises
    ------
    RuntimeError
        After writing the summary, if any study failed (the message names them).
    """
    out = Path(out)
    names = list(STUDY_NAMES) if names is None else list(names)
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ValueError(f"`workers` = {workers!r}: give a positive integer")
    done = {}
    with progress.bar(len(names), "studies") as bar:

        def report_in_order():
            # a study's line once every study before it has its own: the order of names
            while len(done) < len(names) and names[len(done)] in pending:
                name = names[len(done)]
                done[name] = pending.pop(name)
                progress.report(done[name][1])
                bar.update()

        pending = {}
        if workers == 1 or len(names) < 2:
            for name in names:
                progress.log(f"running {name} ...")
                pending[name] = _run_entry(name, out, seed, progress)
                report_in_order()
        else:
            order = [n for n in LONGEST_FIRST if n in names]
            order += [n for n in names if n not in order]
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init) as ex:
                futures = {ex.submit(_run_in_worker, n, out, seed): n for n in order}
                for fut in as_completed(futures):
                    pending[futures[fut]] = fut.result()
                    report_in_order()
    entries = [done[name][0] for name in names]
    failed = [done[name][2] for name in names if done[name][2] is not None]
    write_atomic(out / "summary.md", render_summary(entries))
    progress.report(f"wrote {out / 'summary.md'}")
    if failed:
        raise RuntimeError("studies failed: " + "; ".join(failed))
    return entries
