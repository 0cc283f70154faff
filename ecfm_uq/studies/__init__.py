"""Study modules, one per paper section. Each exposes

``NAME``, ``DESCRIPTION``,
``add_arguments(parser)`` : study options for ``ecfm-uq reproduce NAME``,
``settings_from_args(args) -> dict`` : the settings recorded in ``result.json``,
``run(settings, out_dir, progress) -> dict`` : runs the study, writes figures into
``out_dir`` and returns the result (written by the caller as ``result.json``),
``summary_rows(result) -> list[dict]`` : rows ``quantity, paper, ours, holds`` for
``summary.md``.
"""

import argparse
import importlib
import importlib.util
import time
from pathlib import Path

from ._common import write_json

STUDY_NAMES = (
    "burgers",
    "kpp",
    "beam",
    "mc",
    "boundary",
    "geometry",
    "coverage",
    "missing-physics",
    "ode",
)

__all__ = [
    "STUDY_NAMES",
    "add_common_arguments",
    "available_studies",
    "check_requirements",
    "default_settings",
    "load_study",
    "missing_requirements",
    "run_study",
]


def _module_name(name):
    return name.replace("-", "_")


def load_study(name):
    """Import ``ecfm_uq.studies.<name>``."""
    return importlib.import_module(f"ecfm_uq.studies.{_module_name(name)}")


#: the extra that installs a study's optional requirement (``pip install -e ".[extra]"``)
EXTRAS = {"skfem": "fem"}


def missing_requirements(name):
    """The optional packages study ``name`` needs and does not have, with their extras."""
    mod = load_study(name)
    return [
        (req, EXTRAS.get(req, req))
        for req in getattr(mod, "REQUIRES", ())
        if importlib.util.find_spec(req) is None
    ]


def check_requirements(name):
    """Raise a RuntimeError naming the extra to install if study ``name`` lacks one."""
    missing = missing_requirements(name)
    if missing:
        req, extra = missing[0]
        raise RuntimeError(
            f'study {name!r} needs {req}, which is not installed: pip install -e ".[{extra}]" '
            f"(or pip install ecfm-uq[{extra}])"
        )


def available_studies():
    """Names of the studies whose requirements (optional extras) are installed."""
    return [name for name in STUDY_NAMES if not missing_requirements(name)]


def add_common_arguments(p):
    """Options every study takes: ``--out``, ``--seed``, ``--quiet``."""
    p.add_argument("--out", required=True, type=Path, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, default=None, help="random seed (study default if omitted)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def default_settings(name, out, seed=None):
    """The settings a study runs with when given no options (the paper's)."""
    mod = load_study(name)
    parser = argparse.ArgumentParser(prog=name)
    add_common_arguments(parser)
    mod.add_arguments(parser)
    argv = ["--out", str(out), "--quiet"] + ([] if seed is None else ["--seed", str(seed)])
    return mod.settings_from_args(parser.parse_args(argv))


def run_study(name, settings, out_root, progress):
    """Run one study with ``settings`` and write ``out_root/name/result.json``."""
    check_requirements(name)
    mod = load_study(name)
    out_dir = Path(out_root) / name
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = mod.run(settings, out_dir, progress)
    result.setdefault("settings", settings)
    result["wall_time_s"] = round(time.perf_counter() - t0, 3)
    write_json(out_dir / "result.json", result)
    return result
