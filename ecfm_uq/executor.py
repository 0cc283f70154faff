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

from ._validation import as_finite_array, as_model_output, check_int
from .errors import ModelEvaluationError
from .memory import check_allocation

__all__ = ["CallerWrapped", "NonFiniteOutputError", "evaluate_samples", "output_array_bytes"]


class CallerWrapped(Exception):  # noqa: N818 (a marker, not an error of its own)
    """Base of a failure a caller's own wrapper of ``fn`` already reports with its sample
    (e.g. :func:`ecfm_uq.mc.verify`): passed through as it is, not wrapped again."""


# Outputs handed to a consumer (not stored) travel in chunks of at most this many bytes.
STREAM_CHUNK_BYTES = 2**20


class NonFiniteOutputError(ValueError):
    """The model returned NaN or inf; ``index`` is the first offending sample's row."""

    def __init__(self, message, index):
        super().__init__(message)
        self.index = index


def _point(x):
    return np.array2string(np.asarray(x), precision=6, threshold=8)


def _user_error(e, name, at, vectorized):
    """A user's exception raised inside ``fn``, re-raised as its own type with the call
    (the function's name and the sample) and a hint; the original chained."""
    if isinstance(e, IndexError | TypeError):
        hint = (
            f"; with vectorized=True `{name}` receives a (k, d) array of k points and must "
            "return k rows (pass vectorized=False for a function of one point)"
            if vectorized
            else f"; `{name}` receives one point, a 1-D array of the inputs (pass "
            "vectorized=True for a function of a (k, d) array of points); check that it "
            "reads no more inputs than there are"
        )
    else:
        hint = ""
    msg = f"`{name}` {at} raised {type(e).__name__}: {e}{hint}"
    try:
        err = type(e)(msg)
    except Exception:  # an exception class with its own signature
        err = ModelEvaluationError(msg)
    return err


def _call(fn, x, name, at, vectorized):
    """``fn(x)`` converted (:func:`~ecfm_uq._validation.as_model_output`); a user's
    exception re-raised naming the call ``at()`` and the sample, the original chained (one
    a caller's wrapper already reports, :class:`CallerWrapped`, passed through)."""
    try:
        out = fn(x)
    except CallerWrapped:
        raise
    except Exception as e:  # a user callback: name the call and the sample(s)
        raise _user_error(e, name, at(), vectorized) from e
    return as_model_output(out, name=name, at=at)


def _evaluate_chunk(fn, part, name="fn"):
    """Evaluate ``fn`` on every sample of ``part = (offset, chunk)`` (the rows from
    ``offset`` on); module-level so it pickles."""
    offset, chunk = part
    outs = []
    for j, s in enumerate(chunk):

        def at(j=j, s=s):
            return f"at sample {offset + j} (x={_point(s)})"

        outs.append(_call(fn, s, name, at, vectorized=False))
    shapes = {o.shape for o in outs}
    if len(shapes) > 1:
        raise ValueError(f"`{name}` returned outputs of different shapes: {sorted(shapes)}")
    return np.stack(outs)


def _evaluate_batch(fn, part, name="fn"):
    """Evaluate a vectorized ``fn`` on a whole chunk, ``part = (offset, chunk)``:
    ``fn(chunk)`` of shape (len(chunk), ...)."""
    offset, chunk = part

    def at():
        return f"at samples {offset}..{offset + len(chunk) - 1} (x={_point(chunk[0])}, ...)"

    out = _call(fn, chunk, name, at, vectorized=True)
    if out.ndim == 0 or out.shape[0] != len(chunk):
        raise ValueError(
            f"a vectorized `{name}` must return one output row per point: got shape "
            f"{out.shape} for {len(chunk)} points (a function of one point? pass "
            "vectorized=False)"
        )
    return out


def output_array_bytes(n, shape):
    """Bytes of the (n, *shape) float array :func:`evaluate_samples` returns."""
    return 8.0 * n * math.prod(shape)


def _check_outputs(n, shape, name):
    """The default check: the (n, *shape) output array, with what a caller can do instead."""
    m = math.prod(shape)
    check_allocation(
        output_array_bytes(n, shape),
        f"the outputs of {n} runs of `{name}` ({m} values each, shape {tuple(shape)})",
        f"let `{name}` return only the values you need (e.g. the sensors M_obs @ u or a "
        "coarser field), or evaluate `samples` in slices and reduce each slice as it "
        "arrives (e.g. its running mean and variance)",
    )


def _is_future(obj):
    return hasattr(obj, "result") and callable(obj.result) and not isinstance(obj, np.ndarray)


def evaluate_samples(
    fn,
    samples,
    executor=None,
    *,
    workers=2,
    chunksize=None,
    callback=None,
    name="fn",
    check=None,
    vectorized=False,
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
        ``ThreadPoolExecutor`` or a ``dask.distributed.Client`` (each future's result is
        taken in order as its rows are filled or streamed, never all gathered at once).
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
    check : callable, optional
        ``check(n, shape)``, called once the first sample's output shape is known and
        before the other samples run; it raises (e.g. :class:`~ecfm_uq.errors.MemoryBudgetError`)
        to stop, or returns a callable ``consume(start, block)`` to receive the outputs
        of rows ``start, start + 1, ...`` in order as they finish instead of having them
        stored (then ``None`` is returned: a field compressed as it arrives). Default: refuse an (n, *shape) output array over the memory budget
        (:mod:`ecfm_uq.memory`), naming the cheaper calls. A caller that needs more
        memory per output (a fit's work arrays) passes its own check, which should include
        :func:`output_array_bytes`.
    vectorized : bool
        ``fn`` takes a whole chunk of samples, (k, ...) → (k, *shape), instead of one
        sample: one call per task.

    Returns
    -------
    (n, ...) ndarray or None
        Outputs in the order of ``samples`` (``None`` when ``check`` returned a consumer).

    Raises
    ------
    TypeError
        ``fn`` not callable or not picklable for a process pool; ``executor`` without ``map``.
    ValueError
        Empty or non-finite samples, outputs of different shapes.
    NonFiniteOutputError
        A non-finite output (a ValueError whose ``index`` is the first offending sample).
    MemoryBudgetError
        The output array (or what ``check`` counts) would exceed the memory budget; only
        the first sample has run.

    Notes
    -----
    The first sample runs alone (through the executor) so that the output array can be
    sized and checked before the other ``n - 1`` runs; the outputs are then written into
    that one array as the chunks finish, so the (n, *shape) result is held once.
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
    chunks = [(0, samples[:1])] + [(i, samples[i : i + chunksize]) for i in range(1, n, chunksize)]
    task = functools.partial(_evaluate_batch if vectorized else _evaluate_chunk, fn, name=name)

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

    def run(parts):
        if executor is None:
            return map(task, parts)
        return executor.map(task, parts)

    out = consume = shape = None
    start = 0
    try:
        # the first sample alone: its shape sizes (and checks) the output array
        # the second map is submitted only after the first result has passed the check
        for k in range(2):
            part = chunks[:1] if k == 0 else chunks[1:]
            if consume is not None and k == 1:
                # streamed: small chunks, so that little is in flight at once
                step = max(1, min(chunksize, int(STREAM_CHUNK_BYTES // (8 * math.prod(shape)))))
                part = [(i, samples[i : i + step]) for i in range(1, n, step)]
            if not part:
                continue
            for r in run(part):
                r = r.result() if _is_future(r) else r
                if shape is None:
                    shape = r.shape[1:]
                    consume = (check or functools.partial(_check_outputs, name=name))(n, shape)
                    if not callable(consume):
                        consume = None
                        out = np.empty((n, *shape))
                if r.shape[1:] != shape:
                    raise ValueError(
                        f"`{name}` returned outputs of different shapes: {shape} for "
                        f"sample 0 and {r.shape[1:]} for a sample in rows {start}.."
                        f"{start + len(r) - 1}"
                    )
                bad = ~np.isfinite(r.reshape(len(r), -1)).all(axis=1)
                if bad.any():
                    i = start + int(np.argmax(bad))
                    raise NonFiniteOutputError(
                        f"`{name}` returned NaN or inf for sample {i} ({samples[i]!r}); "
                        "check the model at that germ value",
                        i,
                    )
                if consume is None:
                    out[start : start + len(r)] = r
                else:
                    consume(start, r)
                start += len(r)
                if callback is not None:
                    callback(len(r))
    finally:
        if own_pool:
            executor.shutdown(wait=True, cancel_futures=True)
    if start != n:
        raise RuntimeError(
            f"`executor` returned results for {start} of {n} samples; its map(f, chunks) "
            "must return one result per chunk, in order"
        )
    return out
