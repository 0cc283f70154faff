"""Memory budget: refuse an allocation before making it, with the size and the way out.

Every large allocation in the engine (a dense ``(NP)^2`` Jacobian, its LU factors, an
assembled sparse block matrix, Krylov work vectors, an (N, N) covariance, the Gram
matrices and designs of the chaos regressions) is checked here first. The budget
defaults to 80 % of the machine's physical memory; change it with
:func:`set_memory_budget` or the environment variable ``ECFM_UQ_MEMORY_BUDGET`` (bytes,
or with a suffix ``K``, ``M``, ``G``).
"""

from __future__ import annotations

import functools
import os

from .errors import MemoryBudgetError

__all__ = [
    "check_allocation",
    "check_covariance",
    "format_bytes",
    "memory_budget",
    "set_memory_budget",
]

_DEFAULT_FRACTION = 0.8
_budget_override = None


@functools.cache
def _physical_memory():
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: assume a small machine
        return 8 * 2**30


def _parse_bytes(text):
    text = text.strip().upper()
    scale = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    try:
        if text and text[-1] in scale:
            return float(text[:-1]) * scale[text[-1]]
        return float(text)
    except ValueError as e:
        raise ValueError(
            f"ECFM_UQ_MEMORY_BUDGET={text!r} is not a size; use bytes or e.g. '8G'"
        ) from e


def memory_budget():
    """The current budget in bytes (override, else environment, else 80 % of RAM)."""
    if _budget_override is not None:
        return _budget_override
    env = os.environ.get("ECFM_UQ_MEMORY_BUDGET")
    if env:
        return _parse_bytes(env)
    return _DEFAULT_FRACTION * _physical_memory()


def set_memory_budget(nbytes):
    """Set the budget in bytes; ``None`` restores the default. Returns the previous value."""
    global _budget_override
    previous = _budget_override
    if nbytes is not None:
        if isinstance(nbytes, bool) or not isinstance(nbytes, int | float) or not nbytes > 0:
            raise ValueError(f"`nbytes` must be a positive number of bytes, got {nbytes!r}")
        nbytes = float(nbytes)
    _budget_override = nbytes
    return previous


def format_bytes(n):
    """``1.5e9 -> '1.40 GiB'``."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{int(n)} B"


def check_allocation(nbytes, what, alternatives):
    """Raise :class:`MemoryBudgetError` if ``nbytes`` exceeds the budget.

    Parameters
    ----------
    nbytes : float
        Size the operation would allocate.
    what : str
        What would be allocated (e.g. ``"dense Jacobian of size NP = 14000"``).
    alternatives : str
        The options that avoid it (e.g. ``"pass solver='cg'"``).
    """
    budget = memory_budget()
    if nbytes > budget:
        raise MemoryBudgetError(
            f"{what} needs {format_bytes(nbytes)}, over the memory budget of "
            f"{format_bytes(budget)}; {alternatives} (or raise the budget with "
            "ecfm_uq.memory.set_memory_budget)"
        )
    return nbytes


def check_covariance(N, what="covariance", cheaper="variance(Theta)", copies=2):
    """Refuse an (N, N) covariance matrix that would not fit, naming the cheaper call.

    Forming :math:`\\Theta\\,\\mathbb E[\\Psi\\Psi^T]\\,\\Theta^T - \\mu\\mu^T` holds two
    (N, N) float arrays at its peak (the product and the outer product), so
    ``copies = 2`` by default.

    Parameters
    ----------
    N : int
        Number of field values (rows of the covariance).
    what : str
        The call that would allocate it, for the message.
    cheaper : str
        The call that gives what is usually wanted without the (N, N) matrix.
    copies : int
        (N, N) arrays alive at the peak.

    Returns
    -------
    float
        The bytes that will be allocated.

    Raises
    ------
    MemoryBudgetError
        If ``copies * 8 * N**2`` bytes exceed the budget; the message names ``cheaper``.
    """
    N = int(N)
    return check_allocation(
        8.0 * copies * N * N,
        f"the ({N}, {N}) {what}",
        f"call {cheaper} for the pointwise variances (shape ({N},)), or take the "
        "covariance of the few rows you need (e.g. Theta[idx] or M_obs @ Theta)",
    )
