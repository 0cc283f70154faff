"""Plumbing shared by the study modules: atomic output and progress (figures: ``ecfm_uq.plotting``).

Study modules hold no numerics: they read settings, call the library, and write
``result.json`` plus figures through these helpers.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from .._files import atomic_path


def to_jsonable(obj):
    """Convert numpy scalars/arrays (recursively) to plain JSON types.

    Raises ValueError on NaN or inf: a result never hides a non-finite number.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        v = float(obj)
        if not np.isfinite(v):
            raise ValueError(f"non-finite number {v} in a result; refusing to write it")
        return v
    return obj


def write_atomic(path, data, mode="w"):
    """Write ``data`` to ``path`` via a temporary file and an atomic rename."""
    with atomic_path(path, suffix=".tmp") as tmp, open(tmp, mode) as fh:
        fh.write(data)


def write_json(path, result):
    """Write a result dictionary as pretty JSON, atomically."""
    write_atomic(path, json.dumps(to_jsonable(result), indent=2, sort_keys=True) + "\n")


class Progress:
    """A progress bar on a terminal, silent otherwise or when ``quiet``.

    Use as ``with progress.bar(total, desc) as bar: bar.update()``.
    """

    def __init__(self, quiet=False, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.quiet = quiet
        self.enabled = (not quiet) and hasattr(self.stream, "isatty") and self.stream.isatty()

    def bar(self, total, desc):
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, disable=not self.enabled, file=self.stream, leave=False)

    def log(self, msg):
        """A line on a terminal only (progress detail)."""
        if self.enabled:
            print(msg, file=self.stream)

    def report(self, msg):
        """A line on any stream, a terminal or a log file, unless ``quiet``."""
        if not self.quiet:
            print(msg, file=self.stream, flush=True)


QUIET = Progress(quiet=True)
