"""The validated arguments of :func:`~ecfm_uq.inverse.fit`, as the fitters receive them.

One frozen object handed down from the entry point to the formulation that runs: no
fitter imports the entry point, and a walk of ``sigma`` or ``tol`` from ``fit`` goes down.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

__all__ = ["FitSettings", "check_least_squares_options"]


@dataclass(frozen=True)
class FitSettings:
    """The validated arguments of :func:`fit`, handed to the problem kind's fitter.

    ``sigma_label`` is how the fitter's messages name the noise where the number
    ``sigma`` would mislead: an array ``sigma`` is whitened once and the fitter runs on
    the whitened problem with ``sigma = 1``, so its messages say ``"sigma=1 (whitened:
    sigma per observation (0.015 to 0.055))"``, the noise as given; ``None`` (the
    default): ``sigma`` is the noise as given, written as its number.
    """

    formulation: str
    method: str
    sigma: object
    bounds: list | None
    tol: float | None
    maxiter: int | None
    options: dict
    uncertainty: bool
    alpha: float
    sigma_label: str | None = None

    def take(self, known):
        """``options`` completed by the defaults in ``known`` (name -> default).

        Raises TypeError naming any option this formulation and method do not know.
        """
        unknown = sorted(set(self.options) - set(known))
        if unknown:
            raise TypeError(
                f"`options` has unknown name(s) {unknown} for formulation="
                f"{self.formulation!r}, method={self.method!r}; known: {sorted(known)}"
            )
        return {**known, **self.options}


def check_least_squares_options(options, p):
    """The values of the least-squares ``options`` checked by name (their names were, by
    :meth:`FitSettings.take`): ``x_scale`` ``"jac"`` or ``p`` positive numbers;
    ``ftol``, ``xtol``, ``gtol`` non-negative numbers or None; ``polish`` a bool.

    Raises
    ------
    TypeError, ValueError
        Naming the option and the values it takes (scipy's messages name neither).
    """
    x_scale = options.get("x_scale", "jac")
    if isinstance(x_scale, str):
        if x_scale != "jac":
            raise ValueError(
                f"options['x_scale'] must be 'jac' (scale by the Jacobian's columns, the "
                f"default) or {p} positive numbers, one per parameter, got {x_scale!r}"
            )
    else:
        arr = np.asarray(x_scale, dtype=object).ravel()
        ok = arr.size in (1, p) and all(
            isinstance(v, numbers.Real) and not isinstance(v, bool) and np.isfinite(v) and v > 0
            for v in arr
        )
        if not ok:
            raise ValueError(
                f"options['x_scale'] must be 'jac' or {p} positive numbers (one per "
                f"parameter), got {x_scale!r}"
            )
    for key in ("ftol", "xtol", "gtol"):
        v = options.get(key)
        if type(v) is float and 0.0 <= v < math.inf:  # the defaults' type: no ABC check
            continue
        if v is not None and (
            isinstance(v, bool) or not isinstance(v, numbers.Real) or not np.isfinite(v) or v < 0
        ):
            raise ValueError(f"options[{key!r}] must be a number >= 0 or None, got {v!r}")
    polish = options.get("polish", True)
    if type(polish) is not bool and not isinstance(polish, np.bool_):
        raise TypeError(f"options['polish'] must be True or False, got {options['polish']!r}")
    return options
