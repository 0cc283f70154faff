"""Thread use decided by the library, not by the caller's environment (issue 21 item 4).

The engine's hot paths are many small dense LU factorizations and multi-right-hand-side
triangular solves (Newton on (NP)-sized Jacobians, the mean block of a preconditioner
applied to all P chaos columns, compiled kernels). A threaded BLAS splits each of them
across the cores and spends more on synchronization than it gains: measured on 2 cores,
a 2-D transient Galerkin march takes 18.8 s with OpenBLAS's default threads against 5.0 s
with one (``benchmarks/threads.py`` repeats the comparison). Large dense factorizations
do gain from threads.

So every engine entry point (:func:`~ecfm_uq.system.solve_steady`,
:func:`~ecfm_uq.system.march`, the inverse fits, Monte Carlo runs) executes inside
:func:`blas_threads`, which limits BLAS to one thread unless the problem is large
(``n_unknowns >= LARGE_DENSE``, where the dense factorization dominates) — whatever
``OPENBLAS_NUM_THREADS`` says. The limit is applied once at the outermost entry (nested
calls are free) through the BLAS libraries of one
:class:`threadpoolctl.ThreadpoolController`, found once: an entry reads each library's
threads and sets only those that differ (a few microseconds; threadpoolctl's own
``limit`` re-reads every library's information and costs ten times that, as much as a
whole small fit's optimizer). A call with no dense work of the library's own
(``n_unknowns == 0``, :data:`NO_DENSE`: a fit of a user's Python function, whose only
dense algebra is an n-by-p SVD) leaves the threads as the caller set them and switches
nothing. :func:`set_blas_threads` overrides the decision for a session (``None``
restores it).
"""

from __future__ import annotations

import contextlib
import functools
import threading

__all__ = ["LARGE_DENSE", "NO_DENSE", "blas_threads", "library_threads", "set_blas_threads"]

#: dense systems with at least this many unknowns are left to the threaded BLAS (a dense
#: LU of n unknowns costs n^3 / 3 flops: at 2 000 it is ~3e9 and threads pay off)
LARGE_DENSE = 2000
#: ``n_unknowns`` of a call that factorizes nothing of note itself (a fit of a user's
#: function): the threads are left as they are, and nested engine calls decide their own
NO_DENSE = 0

_state = threading.local()
_override = {"threads": None, "set": False}


@functools.cache
def _controller():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@functools.cache
def _blas_libraries():
    """The BLAS libraries' controllers, found once (at the first switching entry)."""
    return tuple(lib for lib in _controller().lib_controllers if lib.user_api == "blas")


@contextlib.contextmanager
def _limited(limit):
    """Each BLAS library at ``limit`` threads inside, restored after (only the libraries
    whose threads differ are set)."""
    libs = _blas_libraries()
    changed = []
    try:
        for lib in libs:
            old = lib.get_num_threads()
            if old is not None and old != limit:
                lib.set_num_threads(limit)
                changed.append((lib, old))
        yield
    finally:
        for lib, old in reversed(changed):
            lib.set_num_threads(old)


def set_blas_threads(threads):
    """Override the library's choice of BLAS threads (``None``: the library decides).

    Parameters
    ----------
    threads : int or None
        Threads every engine entry point runs its BLAS with.
    """
    if threads is not None:
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"`threads` must be a positive int or None, got {threads!r}")
    _override["threads"] = threads
    _override["set"] = threads is not None


@contextlib.contextmanager
def blas_threads(n_unknowns=None):
    """BLAS threads for one engine call: 1 for small dense work, unlimited for large.

    Parameters
    ----------
    n_unknowns : int, optional
        Size of the largest dense system the call factorizes; ``None`` means small,
        :data:`NO_DENSE` (0) none at all: nothing is switched.
    """
    if n_unknowns == NO_DENSE and not _override["set"]:  # nothing of ours to decide
        yield
        return
    if getattr(_state, "depth", 0):  # an outer entry point already decided
        _state.depth += 1
        try:
            yield
        finally:
            _state.depth -= 1
        return
    if _override["set"]:
        limit = _override["threads"]
    else:
        limit = None if (n_unknowns is not None and n_unknowns >= LARGE_DENSE) else 1
    _state.depth = 1
    try:
        if limit is None:
            yield
        else:
            with _limited(limit):
                yield
    finally:
        _state.depth = 0


def library_threads(size=None):
    """Decorator running a function inside :func:`blas_threads`.

    ``size``, if given, maps the call's arguments to ``n_unknowns``.
    """

    def wrap(func):
        @functools.wraps(func)
        def inner(*args, **kwargs):
            n = None
            if size is not None:
                try:
                    n = size(*args, **kwargs)
                except Exception:  # sizing is advisory: a bad argument fails in func
                    n = None
            if n == NO_DENSE and not _override["set"]:  # nothing to switch (see above)
                return func(*args, **kwargs)
            with blas_threads(n):
                return func(*args, **kwargs)

        return inner

    return wrap
