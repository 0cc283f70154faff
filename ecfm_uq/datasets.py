"""Data sets shipped with the package (``ecfm_uq/data/``, sources in its README)."""

from __future__ import annotations

from importlib import resources

import numpy as np

__all__ = ["lynx_hare"]


def lynx_hare():
    """The Hudson Bay Company lynx and snowshoe hare pelts, 1900-1920.

    Annual pelt counts in thousands, the classic predator-prey data set (Hudson Bay
    Company records as compiled by Howard, 2009); 21 years, no missing values.

    Returns
    -------
    years : (21,) ndarray
    pelts : (21, 2) ndarray
        Columns: hare, lynx.
    """
    with resources.files("ecfm_uq").joinpath("data/lynx_hare.csv").open() as f:
        table = np.loadtxt(f, delimiter=",", skiprows=1)
    return table[:, 0], table[:, 1:]
