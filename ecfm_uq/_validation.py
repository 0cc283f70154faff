"""Argument checks shared by the public API (validate once, at the boundary)."""

from __future__ import annotations

import math
import numbers

import numpy as np
import scipy.sparse as sp


def as_finite_array(name, value, *, ndim=None, shape=None, dtype=float):
    """Return ``value`` as a finite ndarray or raise a ValueError naming ``name``.

    ``shape`` may contain ``None`` for free axes.
    """
    if type(value) is np.ndarray and value.dtype is _FLOAT64 and dtype is float:
        arr = value  # what np.asarray(value, dtype=float) returns: the array itself
    else:
        if isinstance(value, str | bytes):
            raise TypeError(f"`{name}` must be array-like of numbers, got {describe(value)}")
        try:
            arr = np.asarray(value, dtype=dtype)
        except (TypeError, ValueError) as e:
            raise TypeError(f"`{name}` must be array-like of numbers, got {describe(value)}") from e
        if arr.dtype == object:
            raise TypeError(f"`{name}` must be array-like of numbers, got {describe(value)}")
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"`{name}` must be {ndim}-D, got shape {arr.shape}")
    if shape is not None and arr.shape != shape:
        if arr.ndim != len(shape) or any(
            s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)
        ):
            want = tuple("any" if s is None else s for s in shape)
            raise ValueError(f"`{name}` must have shape {want}, got {arr.shape}")
    if not all_finite(arr):
        raise ValueError(f"`{name}` contains NaN or inf; pass finite values only")
    return arr


def all_finite(arr):
    """Whether every value of the float array ``arr`` is finite: a finite sum says so (NaN
    and inf propagate through it) in one reduction -- for a float64 array that is 1-D or
    contiguous the inner product with ones (one BLAS call, a third of ``arr.sum()``'s
    cost, the same overflow only when the sum overflows); the elementwise test runs only
    when the sum is not finite (a bad value, or finite values whose sum overflows)."""
    if (
        type(arr) is np.ndarray
        and arr.dtype is _FLOAT64
        and (arr.ndim == 1 or arr.flags.c_contiguous)
    ):
        if arr.ndim != 1:  # a contiguous array's flat view: the same values
            arr = arr.reshape(-1)
        n = arr.shape[0]
        if n <= 16:  # a few values (a covariance, a gradient): their Python sum is cheaper
            if math.isfinite(sum(arr.tolist())):
                return True
            return bool(np.isfinite(arr).all())
        if n <= _ONES_MAX:
            ones = _ones[0]
            if ones.shape[0] < n:
                ones = _ones[0] = np.ones(max(n, 2 * ones.shape[0]))
            if math.isfinite(arr.dot(ones[:n])):
                return True
            return bool(np.isfinite(arr).all())
    total = _add_reduce(arr, axis=None)
    if type(total) is np.float64:  # without numpy's scalar ufunc call
        return math.isfinite(total) or bool(np.isfinite(arr).all())
    return bool(np.isfinite(total)) or bool(np.isfinite(arr).all())


_add_reduce = np.add.reduce
_FLOAT64 = np.dtype(np.float64)
#: ones for all_finite's inner product, grown on demand (one slot: replaced whole)
_ones = [np.ones(64)]
_ONES_MAX = 1 << 16


def describe(value):
    """``"str 'abc'"``: a user value's type and short repr, for error messages."""
    r = " ".join(repr(value).split())
    if len(r) > 40:
        r = r[:37] + "..."
    return f"{type(value).__name__} {r}"


def check_int(name, value, *, minimum=None):
    """Return ``value`` as int, raising TypeError/ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"`{name}` must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"`{name}` must be >= {minimum}, got {value}")
    return value


def check_real(name, value):
    """A finite real number (not a bool), as float, or a TypeError/ValueError naming it."""
    if type(value) is float and math.isfinite(value):  # the common case, without the ABCs
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"`{name}` must be a real number, got {describe(value)}")
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"`{name}` must be finite, got {value}")
    return value


def check_positive(name, value):
    """Return ``value`` as a positive finite float."""
    if type(value) is float and 0.0 < value < math.inf:  # the common case, without the ABCs
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"`{name}` must be a real number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"`{name}` must be positive and finite, got {value}")
    return value


def check_fraction(name, value, hint=""):
    """A real number strictly between 0 and 1 (a test's size, a level), as float: a
    TypeError for a non-number, a ValueError outside (0, 1), both naming it."""
    value = check_real(name, value)
    if not 0.0 < value < 1.0:
        raise ValueError(f"`{name}` must lie in (0, 1){hint}, got {value}")
    return value


def check_choice(name, value, choices):
    """Raise ValueError unless ``value`` is one of ``choices``."""
    # only strings and numbers compare: an array's == is element-wise, a list never matches
    known = isinstance(value, str | numbers.Number) and any(value == c for c in choices)
    if not known:
        shown = repr(value) if isinstance(value, str) else describe(value)
        raise ValueError(f"unknown `{name}` {shown}; choose one of {sorted(choices, key=str)}")
    return value


def is_sparse(value):
    """True for a ``scipy.sparse`` matrix or array."""
    return sp.issparse(value)


def as_operator(name, value, *, shape=None, square=False):
    """Return ``value`` as a finite dense ``ndarray`` or a CSR ``scipy.sparse`` matrix.

    Dense input goes through :func:`as_finite_array` unchanged (2-D); sparse input is kept
    sparse (converted to CSR, ``float``) with its stored values checked for NaN/inf, so
    nothing of size ``N^2`` is formed for a sparse operator.

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : array_like or scipy.sparse matrix
    shape : tuple, optional
        Required shape; ``None`` entries are free.
    square : bool
        Require a square matrix.
    """
    if sp.issparse(value):
        if value.ndim != 2:
            raise ValueError(f"`{name}` must be 2-D, got shape {value.shape}")
        try:
            out = sp.csr_matrix(value, dtype=float)
        except (TypeError, ValueError) as e:
            raise TypeError(f"`{name}` must hold real numbers, got dtype {value.dtype}") from e
        if not np.all(np.isfinite(out.data)):
            raise ValueError(f"`{name}` contains NaN or inf; pass finite values only")
    else:
        out = as_finite_array(name, value, ndim=2)
    if square and out.shape[0] != out.shape[1]:
        raise ValueError(f"`{name}` must be square, got shape {out.shape}")
    if shape is not None and any(
        s is not None and s != a for s, a in zip(shape, out.shape, strict=True)
    ):
        want = tuple("any" if s is None else s for s in shape)
        raise ValueError(f"`{name}` must have shape {want}, got {out.shape}")
    return out


def as_dense_rows(name, value, *, n_cols=None):
    """A (C, N) matrix with few rows (sensors) as a dense array, from dense or sparse input.

    For formulations whose algebra is dense in the sensors: a ``(C, N)`` array is small
    even when ``N`` is large, so densifying a sparse sensor matrix forms nothing of size
    ``N^2``.
    """
    out = as_operator(name, value, shape=None if n_cols is None else (None, n_cols))
    return out.toarray() if sp.issparse(out) else out


def check_seed(name, seed):
    """A seed numpy accepts, checked: ``None``, an int >= 0, a sequence of such ints, a
    ``numpy.random.Generator``, ``BitGenerator`` or ``SeedSequence``; returned unchanged.

    Raises
    ------
    TypeError, ValueError
        Naming ``name``, for a string, a float, a bool or a negative integer (numpy's own
        messages name neither the argument nor the fix).
    """
    if seed is None or isinstance(
        seed, np.random.Generator | np.random.BitGenerator | np.random.SeedSequence
    ):
        return seed
    fix = "pass an integer >= 0 (e.g. seed=0), a numpy.random.Generator or None"
    values = seed if isinstance(seed, list | tuple | np.ndarray) else [seed]
    for v in np.ravel(np.asarray(values, dtype=object)) if len(values) else [None]:
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise TypeError(f"`{name}` must be a seed, got {describe(seed)}; {fix}")
        if v < 0:
            raise ValueError(f"`{name}` must be >= 0, got {seed!r}; {fix}")
    return seed


def rng_from_seed(name, seed):
    """``numpy.random.default_rng(seed)`` after :func:`check_seed` (the same generator)."""
    return np.random.default_rng(check_seed(name, seed))


def check_level(name, level):
    """A confidence level in (0, 1), as float; a percentage (``95``, ``"95%"``) or a
    string is refused with the fraction to pass instead."""
    if isinstance(level, str):
        text = level.strip().rstrip("%").strip()
        try:
            hint = f"; pass {float(text) / 100:g}" if level.strip().endswith("%") else ""
        except ValueError:
            hint = ""
        raise TypeError(f"`{name}` must be a number in (0, 1) (e.g. 0.95), got str {level!r}{hint}")
    level = check_real(name, level)
    if 1.0 < level < 100.0:
        hint = f"; a percentage? pass {level / 100:g}" if level >= 50 else ""
        raise ValueError(
            f"`{name}` must be in (0, 1), a fraction (0.95 for a 95 % level), got {level:g}{hint}"
        )
    if not 0.0 < level < 1.0:
        raise ValueError(f"`{name}` must be in (0, 1) (e.g. 0.95), got {level:g}")
    return level


def as_model_output(value, *, name, at, shape=None, complex_ok=False):
    """What a user's function returned, as a fresh float (or complex) ndarray.

    The one converter of user-function outputs: ``None``, a tuple of several things,
    strings or objects are refused; complex values are refused unless ``complex_ok``
    (a complex-step derivative); the output is *copied*, so a function that returns the
    same buffer every call (overwriting it) cannot change an output already taken.

    Parameters
    ----------
    value : object
        The return value.
    name : str
        The function's argument name (``"model"``, ``"fn"``, ``"jac"``).
    at : str or callable
        Where it was called (``"at eps=[1. 2.]"``, ``"at sample 3 (x=[...])"``), or a
        function of no argument returning it (formatted only for a message: an array's
        text costs more than the call it describes).
    shape : tuple, optional
        The shape required (the data's); a return whose shape differs only by axes of
        length 1 is accepted (and reshaped), any other shape refused.
    complex_ok : bool
        Keep complex values (``jac="cs"``); else a complex return is a TypeError.

    Raises
    ------
    TypeError
        ``None``, a tuple/list that is not an array of numbers, complex values.
    ValueError
        The wrong shape.
    """

    if (
        type(value) is np.ndarray
        and value.dtype is _FLOAT64
        and (shape is None or value.shape == shape)
    ):  # the common case (a float64 array of the data's shape): one copy, no checks
        return value.copy()

    def where():
        return f"`{name}` {at() if callable(at) else at}"

    if value is None:
        raise TypeError(
            f"{where()} returned None; `{name}` must return its values (did it forget `return`?)"
        )
    if (
        isinstance(value, tuple)
        and len(value) > 1
        and any(isinstance(v, np.ndarray | list | tuple | str | dict) or v is None for v in value)
    ):
        raise TypeError(
            f"{where()} returned a tuple of {len(value)} items ({describe(value)}); return one "
            "array of values, not (values, extra)"
        )
    try:
        arr = np.array(value, copy=True)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{where()} returned {describe(value)}, not an array of numbers") from e
    if arr.dtype == object or arr.dtype.kind not in "biufc":
        raise TypeError(f"{where()} returned {describe(value)}, not an array of numbers")
    if arr.dtype.kind == "c":
        if not complex_ok:
            raise TypeError(
                f"{where()} returned complex values (dtype {arr.dtype}); `{name}` must return "
                "real numbers: take .real only if the imaginary part is meant to be zero"
            )
    else:
        arr = arr.astype(float, copy=False)
    if shape is not None and arr.shape != tuple(shape):
        squeezed = tuple(s for s in arr.shape if s != 1) == tuple(s for s in shape if s != 1)
        if not squeezed or arr.size != math.prod(shape):
            raise ValueError(
                f"{where()} returned shape {arr.shape}; the data have shape {tuple(shape)}: "
                f"return one value per observation, in the data's shape"
                + (
                    f" (reshape a flat prediction: y.reshape{tuple(shape)})"
                    if arr.size == math.prod(shape)
                    else ""
                )
            )
        arr = arr.reshape(shape)
    return arr
