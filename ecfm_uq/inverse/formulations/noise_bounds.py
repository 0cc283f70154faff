"""Confidence bounds on the sample mean and variance of a noise-only discrepancy
(paper Section 3.2, the bounds of Eq. ecfm_noise).

If :math:`e_i \\sim N(0, \\sigma^2)` i.i.d., :math:`i = 1..C`, then

.. math::

    \\bar e = \\frac1C\\sum_i e_i \\sim N(0, \\sigma^2/C), \\qquad
    s^2 = \\frac{1}{C-1}\\Big(\\sum_i e_i^2 - \\frac1C\\big(\\sum_i e_i\\big)^2\\Big)
        \\sim \\frac{\\sigma^2}{C-1}\\chi^2(C-1),

so the :math:`(1-\\alpha)` confidence intervals are

.. math::

    \\ell_1 = z_{\\alpha/2}\\frac{\\sigma}{\\sqrt C},\\quad \\ell_2 = -\\ell_1,\\qquad
    p_1 = \\chi^2_{\\alpha/2, C-1}\\frac{\\sigma^2}{C-1},\\quad
    p_2 = \\chi^2_{1-\\alpha/2, C-1}\\frac{\\sigma^2}{C-1},

with :math:`z_{\\alpha/2}` and :math:`\\chi^2_{q, C-1}` the quantiles (inverse CDFs) of the
standard normal and of the chi-squared distribution with C - 1 degrees of freedom. For
:math:`\\alpha = 0.05`, C = 225 the paper prints :math:`z = -1.96`, :math:`\\chi^2 = 184.44`
and 267.35.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..._validation import as_finite_array, check_fraction, check_int, check_positive


def _check_sigma(sigma):
    try:
        return check_positive("sigma", sigma)
    except ValueError as e:
        raise ValueError(f"{e}; `sigma` is the known noise standard deviation") from e


def noise_bounds(sigma, n_sensors, alpha=0.05):
    """Bounds :math:`\\ell_1, \\ell_2` (sample mean) and :math:`p_1, p_2` (sample variance).

    Parameters
    ----------
    sigma : float
        Noise standard deviation, > 0.
    n_sensors : int
        Number of measurements C, >= 2 (a sample variance needs two values).
    alpha : float
        Significance level in (0, 1); the intervals have coverage :math:`1 - \\alpha`.

    Returns
    -------
    dict
        ``l1, l2, p1, p2`` and the quantiles ``z`` (:math:`z_{\\alpha/2} < 0`),
        ``chi2_lo`` (:math:`\\chi^2_{\\alpha/2, C-1}`), ``chi2_hi``
        (:math:`\\chi^2_{1-\\alpha/2, C-1}`), plus ``sigma, n_sensors, alpha``.
    """
    sigma = _check_sigma(sigma)
    C = check_int("n_sensors", n_sensors, minimum=1)
    if C < 2:
        raise ValueError(
            f"`n_sensors` must be >= 2 for a sample-variance bound (C - 1 degrees of "
            f"freedom), got {C}"
        )
    alpha = check_fraction("alpha", alpha, " (e.g. 0.05 for 95 % bounds)")
    z = float(stats.norm.ppf(alpha / 2))
    chi2_lo = float(stats.chi2.ppf(alpha / 2, C - 1))
    chi2_hi = float(stats.chi2.ppf(1 - alpha / 2, C - 1))
    l1 = z * sigma / np.sqrt(C)
    return {
        "l1": l1,
        "l2": -l1,
        "p1": chi2_lo * sigma**2 / (C - 1),
        "p2": chi2_hi * sigma**2 / (C - 1),
        "z": z,
        "chi2_lo": chi2_lo,
        "chi2_hi": chi2_hi,
        "sigma": sigma,
        "n_sensors": C,
        "alpha": alpha,
    }


def sample_moments(e):
    """Sample mean and unbiased sample variance of a discrepancy vector.

    Parameters
    ----------
    e : (C,) array_like

    Returns
    -------
    mean, var : float
        :math:`\\bar e` and :math:`s^2` as in Eq. (ecfm_noise).

    Notes
    -----
    The variance is evaluated on the centred values :math:`d = e - \\bar e` as
    :math:`(\\sum d_i^2 - (\\sum d_i)^2/C)/(C-1)` (the paper's formula applied to
    :math:`d`, equal in exact arithmetic). The formula applied to :math:`e` itself
    cancels catastrophically when :math:`|\\bar e|` is large against the spread (a biased
    discrepancy) and can even turn negative.
    """
    e = as_finite_array("e", e, ndim=1)
    C = e.size
    if C < 2:
        raise ValueError(f"`e` must have at least 2 entries for a sample variance, got {C}")
    mean = float(np.mean(e))
    d = e - mean
    sd = float(d.sum())
    return mean, max(float(d @ d) - sd * sd / C, 0.0) / (C - 1)


@dataclass(frozen=True)
class ConsistencyTest:
    """Outcome of :func:`consistency_test`.

    Attributes
    ----------
    mean, var : float
        Sample mean and variance of the discrepancy.
    bounds : dict
        As returned by :func:`noise_bounds`.
    mean_ok, var_ok : bool
        Whether the mean lies in ``[l1, l2]`` and the variance in ``[p1, p2]``.
    """

    mean: float
    var: float
    bounds: dict
    mean_ok: bool
    var_ok: bool

    @property
    def consistent(self):
        """Both moments inside their bounds (data consistent with noise alone)."""
        return self.mean_ok and self.var_ok

    @property
    def mean_rejects(self):
        """The mean test rejects the noise-only hypothesis."""
        return not self.mean_ok

    @property
    def var_rejects(self):
        """The variance test rejects the noise-only hypothesis."""
        return not self.var_ok


def consistency_test(e, sigma, alpha=0.05, rtol=0.0):
    """Test whether a discrepancy :math:`e = \\mathcal M\\theta - v` looks like pure noise.

    Two-sided :math:`(1-\\alpha)` tests of the sample mean against :math:`[\\ell_1, \\ell_2]`
    and of the sample variance against :math:`[p_1, p_2]` (see :func:`noise_bounds`).

    Parameters
    ----------
    e : (C,) array_like
        Discrepancy, C >= 2, finite.
    sigma : float
        Noise standard deviation.
    alpha : float
        Significance level in (0, 1).
    rtol : float
        Relative slack on the bounds, for moments that an optimizer has put exactly on a
        bound (its feasibility tolerance); 0 tests the bounds exactly.

    Returns
    -------
    ConsistencyTest
    """
    mean, var = sample_moments(e)
    b = noise_bounds(sigma, np.size(e), alpha)
    if isinstance(rtol, bool) or not isinstance(rtol, numbers.Real) or not (0 <= rtol < 1):
        raise ValueError(f"`rtol` must be a number in [0, 1), got {rtol!r}")
    tol_m = rtol * b["l2"]
    mean_ok = b["l1"] - tol_m <= mean <= b["l2"] + tol_m
    var_ok = b["p1"] * (1 - rtol) <= var <= b["p2"] * (1 + rtol)
    return ConsistencyTest(mean, var, b, bool(mean_ok), bool(var_ok))


__all__ = ["ConsistencyTest", "consistency_test", "noise_bounds", "sample_moments"]
