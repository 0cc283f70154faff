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
)

__all__ = [
    "STUDY_NAMES",
    "add_common_arguments",
    "available_studies",
    "default_settings",
    "load_study",
    "run_study",
]


def _module_name(name):
    return name.replace("-", "_")


def load_study(name):
    """Import ``ecfm_uq.studies.<name>``."""
    return importlib.import_module(f"ecfm_uq.studies.{_module_name(name)}")


def available_studies():
    """Names of the studies whose modules are installed."""
    names = []
    for name in STUDY_NAMES:
        try:
            mod = load_study(name)
        except ModuleNotFoundError as e:
            if e.name != f"ecfm_uq.studies.{_module_name(name)}":
                raise
            continue
        # a study needing an optional extra (e.g. scikit-fem) is skipped without it
        if all(importlib.util.find_spec(req) is not None for req in getattr(mod, "REQUIRES", ())):
            names.append(name)
    return names


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
    mod = load_study(name)
    out_dir = Path(out_root) / name
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = mod.run(settings, out_dir, progress)
    result.setdefault("settings", settings)
    result["wall_time_s"] = round(time.perf_counter() - t0, 3)
    write_json(out_dir / "result.json", result)
    return result
