"""The method-specific settings of :func:`~ecfm_uq.chaos.fit_pce`: ``options=``, checked by name.

General arguments (the model, the inputs, ``method``, ``order``, the runs: ``n_samples``,
``samples``, ``evaluations``, ``seed``, and how they run: ``executor``, ``workers``,
``progress``) stay keywords of ``fit_pce``; what only some methods read is an option of
those methods, as in :func:`ecfm_uq.inverse.fit`:

==============  ===================================================================
method          options (default)
==============  ===================================================================
"quadrature"    ``n_points`` (order + 1), ``index_set`` ("tensor")
"smolyak"       ``rule`` ("gauss")
"lstsq"         ``design`` ("lhs"), ``index_set`` ("total")
"lars", "omp"   ``design`` ("lhs"), ``q_norm`` (None: adaptive), ``early_stop`` (2),
                ``compress`` (None: above 64 output values), ``compress_tol`` (1e-6),
                ``index_set`` ("total" only)
==============  ===================================================================

A name the method does not read is refused, naming the ones it does, before any model
run. The v0.4 spelling, each option a keyword of ``fit_pce``, works for one more release
with a ``DeprecationWarning`` naming the ``options=`` spelling.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

__all__ = ["METHOD_OPTIONS", "OPTION_DEFAULTS", "UNSET", "method_options"]

#: Default of every option (the v0.4 keywords' defaults).
OPTION_DEFAULTS = {
    "design": "lhs",
    "index_set": None,
    "n_points": None,
    "rule": "gauss",
    "q_norm": None,
    "early_stop": 2,
    "compress": None,
    "compress_tol": 1e-6,
}
_SPARSE = ("design", "q_norm", "early_stop", "compress", "compress_tol", "index_set")
#: The options each method reads.
METHOD_OPTIONS = {
    "quadrature": ("n_points", "index_set"),
    "smolyak": ("rule",),
    "lstsq": ("design", "index_set"),
    "lars": _SPARSE,
    "omp": _SPARSE,
}


class _Unset:
    """A keyword of the v0.4 spelling that was not passed."""

    def __repr__(self):
        return "UNSET"


#: Default of the deprecated keywords: not passed.
UNSET = _Unset()


def method_options(method, options, keywords):
    """``options`` checked by name for ``method`` and completed by the defaults.

    Parameters
    ----------
    method : str
        A method of :func:`~ecfm_uq.chaos.fit_pce` (already checked).
    options : mapping or None
        The caller's ``options=``.
    keywords : dict
        The deprecated keywords of the v0.4 spelling, name -> value (:data:`UNSET` when
        not passed). A passed one the method reads is taken as an option, with a
        ``DeprecationWarning`` naming the ``options=`` spelling; one it does not read
        (ignored in v0.4, too) with a ``DeprecationWarning`` saying it has no effect.

    Returns
    -------
    dict
        Every option of ``method``, by name.

    Raises
    ------
    TypeError
        ``options`` not a mapping, a name the method does not read (naming those it
        does), or one option given both as a keyword and in ``options``.
    """
    if options is None:
        options = {}
    elif not isinstance(options, Mapping):
        raise TypeError(
            f"`options` must be a dict of method settings by name, e.g. "
            f"options={{'q_norm': 0.75}}, got {type(options).__name__}"
        )
    options = dict(options)
    known = METHOD_OPTIONS[method]
    unknown = sorted(set(options) - set(known), key=str)
    if unknown:
        raise TypeError(
            f"`options` has unknown name(s) {unknown} for method={method!r}; the options of "
            f"{method!r} are {sorted(known)}"
        )
    for name, value in keywords.items():
        if value is UNSET:
            continue
        if name in options:
            raise TypeError(
                f"`{name}` is given twice, as a keyword and in `options`; pass it in `options` only"
            )
        if name in known:
            warnings.warn(
                f"fit_pce({name}=...) is deprecated and will be removed in the next release; "
                f"pass options={{{name!r}: {value!r}}}",
                DeprecationWarning,
                stacklevel=3,
            )
            options[name] = value
        else:
            warnings.warn(
                f"fit_pce({name}=...) is deprecated and has no effect with method={method!r} "
                f"(its options are {sorted(known)}); drop it",
                DeprecationWarning,
                stacklevel=3,
            )
    return {name: options.get(name, OPTION_DEFAULTS[name]) for name in known}
