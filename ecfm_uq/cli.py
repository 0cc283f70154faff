"""The ``ecfm-uq`` command: ``ecfm-uq reproduce STUDY --out DIR [options]``.

Each study writes ``DIR/STUDY/result.json`` (atomically) and its figures; ``all`` runs
every study and writes ``DIR/summary.md``. User mistakes end with a one-line message and
a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
import time

from threadpoolctl import threadpool_limits

from .errors import ConvergenceError, SingularSystemError
from .studies import STUDY_NAMES, add_common_arguments, load_study, run_study
from .studies._common import Progress
from .summary import reproduce_all

EXIT_USAGE = 2
EXIT_FAILED = 1


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors on one line."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"ecfm-uq: error: {message}\n")


def build_parser():
    parser = _Parser(
        prog="ecfm-uq",
        description=(
            "Polynomial chaos and the explicit constraint force method (ECFM) for inverse "
            "problems. `ecfm-uq reproduce STUDY --out DIR` reproduces a section of the paper "
            "and writes DIR/STUDY/result.json plus figures; `reproduce all` runs every study "
            "and writes DIR/summary.md (paper value beside ours)."
        ),
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    rep = sub.add_parser(
        "reproduce",
        help="reproduce a study of the paper",
        description="Reproduce one study of the paper (or all of them).",
    )
    studies = rep.add_subparsers(dest="study", required=True, metavar="STUDY", parser_class=_Parser)
    for name in STUDY_NAMES:  # a study whose extra is missing says so when it runs
        mod = load_study(name)
        # argparse %-formats help strings (the list of studies), not descriptions
        text = mod.DESCRIPTION
        p = studies.add_parser(name, help=text.replace("%", "%%"), description=text)
        add_common_arguments(p)
        mod.add_arguments(p)
    p = studies.add_parser("all", help="every study, plus summary.md")
    add_common_arguments(p)
    p.add_argument(
        "--workers",
        type=int,
        default=2,
        help="studies run at once, each in its own single-threaded process (default 2; "
        "the results do not depend on it)",
    )
    return parser


def _check_out(out):
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".ecfm_uq_write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise OSError(f"--out {out}: cannot write there ({e.strerror or e})") from e


def main(argv=None):
    """Console entry point."""
    parser = build_parser()
    args = parser.parse_args(argv)
    progress = Progress(quiet=args.quiet)
    # the studies' dense solves are small: threaded BLAS only oversubscribes the cores
    blas = threadpool_limits(limits=1, user_api="blas")
    try:
        _check_out(args.out)
        if args.study == "all":
            reproduce_all(args.out, progress, seed=args.seed, workers=args.workers)
        else:
            mod = load_study(args.study)
            settings = mod.settings_from_args(args)
            t0 = time.perf_counter()
            run_study(args.study, settings, args.out, progress)
            progress.report(
                f"{args.study}: {time.perf_counter() - t0:.0f} s, results in "
                f"{args.out / args.study}"
            )
    except (
        ValueError,
        TypeError,
        ConvergenceError,
        SingularSystemError,
        OSError,
        RuntimeError,
    ) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        print(f"ecfm-uq: error: {msg}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("ecfm-uq: interrupted", file=sys.stderr)
        return 130
    finally:
        blas.restore_original_limits()
    return 0


if __name__ == "__main__":
    sys.exit(main())
