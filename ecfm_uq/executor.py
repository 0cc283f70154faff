"""Evaluate a model at many points, serially or through an executor (a leaf module).

Both the non-intrusive chaos fits (:func:`ecfm_uq.chaos.fit_pce`) and the Monte Carlo
verification (:func:`ecfm_uq.mc.monte_carlo`) run a black-box model over a set of points;
this module is the one place that does it, so neither imports the other. It depends on
nothing in ecfm_uq but the input checks.

Public API
----------
evaluate_samples      ``fn`` at each row of ``samples``, in order, through an executor
NonFiniteOutputError  a model output was NaN or inf (``index`` names the sample)
"""

from __future__ import annotations

import functools
import math
import pickle
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ._validation import as_finite_array, check_int

__all__ = ["NonFiniteOutputError", "evaluate_samples"]


class NonFiniteOutputError(ValueError):
    """The model returned NaN or inf; ``index`` is the first offending sample's row."""

    def __init__(self, message, index):
        super().__init__(message)
        self.index = index


def _evaluate_chunk(fn, chunk):
    """Evaluate ``fn`` on every sample of ``chunk``; module-level so it pickles."""
    return np.stack([np.asarray(fn(s), dtype=float) for s in chunk])


def _is_future(obj):
    return hasattr(obj, "result") and callable(obj.result) and not isinstance(obj, np.ndarray)


def evaluate_samples(
    fn, samples, executor=None, *, workers=2, chunksize=None, callback=None, name="fn"
):
    """Evaluate ``fn`` at each sample, in parallel, and stack the outputs.

    Parameters
    ----------
    fn : callable
        ``fn(sample) -> array_like`` of a fixed shape. For a process pool it must be
        picklable: a module-level function or a ``functools.partial`` of one.
    samples : (n, ...) array_like
        The points, drawn by the caller from a seeded generator so the result does not
        depend on the executor.
    executor : object with ``map``, optional
        ``None``: a local ``concurrent.futures.ProcessPoolExecutor(max_workers=workers)``
        (run in-process when ``workers == 1``), created and shut down here. Otherwise any
        executor whose ``map(f, chunks)`` returns results or futures, e.g. a
        ``ThreadPoolExecutor`` or a ``dask.distributed.Client`` (whose futures are
        gathered with ``client.gather``).
    workers : int
        Worker count for the default pool and for the default chunk size.
    chunksize : int, optional
        Samples per task (default ``ceil(n / (4 workers))``).
    callback : callable, optional
        Called with the number of samples in each finished chunk (e.g. a progress bar's
        ``update``).
    name : str
        What the caller calls ``fn`` in its own signature (``"fn"``, ``"model"``), used in
        error messages.

    Returns
    -------
    (n, ...) ndarray
        Outputs in the order of ``samples``.

    Raises
    ------
    TypeError
        ``fn`` not callable or not picklable for a process pool; ``executor`` without ``map``.
    ValueError
        Empty or non-finite samples, outputs of different shapes.
    NonFiniteOutputError
        A non-finite output (a ValueError whose ``index`` is the first offending sample).
    """
    if not callable(fn):
        raise TypeError(f"`{name}` must be callable {name}(sample), got {type(fn).__name__}")
    samples = as_finite_array("samples", samples)
    if samples.ndim == 0 or samples.shape[0] == 0:
        raise ValueError("`samples` must be a non-empty array of shape (n, ...)")
    workers = check_int("workers", workers, minimum=1)
    n = samples.shape[0]
    if chunksize is None:
        chunksize = max(1, math.ceil(n / (4 * workers)))
    chunksize = check_int("chunksize", chunksize, minimum=1)
    if executor is not None and not callable(getattr(executor, "map", None)):
        raise TypeError(
            "`executor` must have a map(f, iterable) method (concurrent.futures executor or "
            f"dask.distributed.Client), got {type(executor).__name__}"
        )
    chunks = [samples[i : i + chunksize] for i in range(0, n, chunksize)]
    task = functools.partial(_evaluate_chunk, fn)

    own_pool = executor is None and workers > 1
    if own_pool:
        try:
            pickle.dumps(fn)
        except Exception as e:
            raise TypeError(
                f"`{name}` must be picklable to run in worker processes: use a module-level "
                "function or functools.partial of one (not a lambda or closure), or pass "
                "workers=1"
            ) from e
        executor = ProcessPoolExecutor(max_workers=workers)
    try:
        if executor is None:
            results = map(task, chunks)
        elif callable(getattr(executor, "gather", None)):
            results = executor.gather(executor.map(task, chunks))
        else:
            results = executor.map(task, chunks)
        parts = []
        for r in results:
            r = r.result() if _is_future(r) else r
            parts.append(r)
            if callback is not None:
                callback(len(r))
    finally:
        if own_pool:
            executor.shutdown(wait=True, cancel_futures=True)
    try:
        out = np.concatenate(parts, axis=0)
    except ValueError as e:
        raise ValueError(f"`{name}` returned outputs of different shapes: {e}") from e
    bad = ~np.isfinite(out.reshape(n, -1)).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise NonFiniteOutputError(
            f"`{name}` returned NaN or inf for sample {i} ({samples[i]!r}); "
            "check the model at that germ value",
            i,
        )
    return out
