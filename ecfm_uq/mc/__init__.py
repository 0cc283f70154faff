"""Monte Carlo and quadrature over deterministic solves, to verify the stochastic Galerkin
PCE (paper Section 3.3, Eqs. pce and stats; SPEC "Monte Carlo vs PCE verification").

The PCE gives the mean and variance of a model output in closed form (Eq. stats). Here
the same statistics are estimated non-intrusively from deterministic solves
:math:`y(\\omega)` at germ samples:

* :func:`monte_carlo` evaluates a picklable ``fn(omega)`` on caller-drawn samples through an
  executor (a local process pool by default; any object with ``map`` works, including a
  ``dask.distributed.Client``), so the numbers do not depend on where they ran;
* :func:`mc_moments` gives :math:`\\bar y`, :math:`s^2` and their standard errors
  :math:`s/\\sqrt n` and :math:`\\sqrt{(m_4 - \\tfrac{n-3}{n-1}s^4)/n}`;
* :func:`quadrature_moments` and :func:`pseudospectral_projection` are the
  high-accuracy Gauss-Legendre references (and the non-intrusive collocation PCE);
* :func:`batch_errors` and :func:`loglog_slope` measure the :math:`n^{-1/2}` decay of
  Monte Carlo errors;
* :func:`sobol_indices` estimates first-order and total Sobol indices of a black-box
  model by sampling (Saltelli 2010, Jansen 1999), with confidence intervals: the
  independent check of a polynomial chaos surrogate's indices;
* :func:`verify` checks any polynomial chaos surrogate against its model by Monte Carlo
  on fresh samples of its inputs: moments with standard errors and z-scores, quantiles,
  the hold-out error, convergence against n, a text summary and plots
  (:class:`VerificationReport`).

Modules: :mod:`~ecfm_uq.mc.sampling` (sampling, moments, references),
:mod:`~ecfm_uq.mc.sobol` (Sobol indices), :mod:`~ecfm_uq.mc.verification`
(:func:`verify`); everything is importable from ``ecfm_uq.mc``.
"""

from .sampling import (
    Moments,
    batch_errors,
    draw_germ,
    loglog_slope,
    mc_moments,
    monte_carlo,
    pseudospectral_projection,
    quadrature_moments,
    relative_error,
)
from .sobol import SobolResult, sobol_indices
from .verification import VerificationReport, verify

__all__ = [
    "Moments",
    "SobolResult",
    "VerificationReport",
    "batch_errors",
    "draw_germ",
    "loglog_slope",
    "mc_moments",
    "monte_carlo",
    "pseudospectral_projection",
    "quadrature_moments",
    "relative_error",
    "sobol_indices",
    "verify",
]
