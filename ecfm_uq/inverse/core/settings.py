"""The validated arguments of :func:`~ecfm_uq.inverse.fit`, as the fitters receive them.

One frozen object handed down from the entry point to the formulation that runs: no
fitter imports the entry point, and a walk of ``sigma`` or ``tol`` from ``fit`` goes down.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FitSettings"]


@dataclass(frozen=True)
class FitSettings:
    """The validated arguments of :func:`fit`, handed to the problem kind's fitter."""

    formulation: str
    method: str
    sigma: object
    bounds: list | None
    tol: float | None
    maxiter: int | None
    options: dict
    uncertainty: bool
    alpha: float

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
