"""The noise of the data as given to a fit: one number, one per observation, or a matrix.

``fit(..., sigma=...)`` takes what the user knows of the noise of the data ``v``:

==================  =======================================  ===========================
``sigma``           meaning                                  whitening :math:`W`
==================  =======================================  ===========================
``None``            unknown (estimated from the residual)    :math:`I`
a number            i.i.d. standard deviation                :math:`I/\\sigma`
``(n,)`` array      standard deviation per observation       :math:`\\mathrm{diag}(1/\\sigma_i)`
``(n, n)`` array    covariance matrix :math:`\\Sigma`           :math:`L^{-1}`, :math:`\\Sigma = LL^T`
==================  =======================================  ===========================

The fit then works on the whitened residual :math:`W(f(\\epsilon) - v)`, whose entries
are independent with unit variance under the noise model (scipy's
``curve_fit(sigma=..., absolute_sigma=True)``; Bates & Watts 1988, Sec. 1.3): least
squares, Gauss-Newton standard errors, the chi-squared verdict and the profile likelihood
all follow from that one transformation. The Cholesky factor is computed once, here.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["NoiseModel", "noise_model"]


@dataclass(frozen=True, eq=False)
class NoiseModel:
    """The whitening of ``n`` data values.

    Attributes
    ----------
    kind : str
        ``"unknown"``, ``"scalar"``, ``"diagonal"`` or ``"covariance"``.
    n : int
    scale : float or (n,) ndarray or None
        The standard deviation(s) (``kind`` scalar or diagonal).
    chol : (n, n) ndarray or None
        Lower Cholesky factor of the covariance (``kind`` covariance).
    unit : str
        What one of the ``n`` values is, for messages (``"reading"``: one of a time
        series' readings, :func:`~ecfm_uq.inverse.problems.whitening.dynamic_noise_model`).
    """

    kind: str
    n: int
    scale: float | np.ndarray | None = None
    chol: np.ndarray | None = None
    unit: str = "observation"

    @property
    def known(self):
        """Whether the noise level is given (else estimated from the residual)."""
        return self.kind != "unknown"

    def whiten(self, r):
        """:math:`W r` for a vector ``r`` (n,) or the columns of a matrix (n, k)."""
        r = np.asarray(r, dtype=float)
        if self.kind in ("unknown",):
            return r
        if self.kind == "covariance":
            return scipy.linalg.solve_triangular(self.chol, r, lower=True, check_finite=False)
        s = (
            self.scale
            if np.ndim(self.scale) == 0
            else self.scale.reshape((-1,) + (1,) * (r.ndim - 1))
        )
        return r / s

    def matrix(self):
        """:math:`W` as a dense (n, n) array (small n: sensors, not readings)."""
        return self.whiten(np.eye(self.n))

    def pull_back(self, D):
        """:math:`DW` for a matrix ``D`` (k, n): a derivative in the whitened data
        :math:`Wv` written as one in the data :math:`v`."""
        D = np.asarray(D, dtype=float)
        if self.kind == "unknown":
            return D
        if self.kind == "covariance":  # D L^{-1} = (L^{-T} D^T)^T
            return scipy.linalg.solve_triangular(
                self.chol, D.T, lower=True, trans="T", check_finite=False
            ).T
        return D / self.scale

    def std(self):
        """The standard deviation of each value: a float (``"scalar"``), the ``(n,)``
        standard deviations (``"diagonal"``), the square roots of the covariance's diagonal
        (``"covariance"``: each value's own noise, correlations left out) or ``None``
        (``"unknown"``)."""
        if self.kind == "scalar":
            return float(self.scale)
        if self.kind == "diagonal":
            return np.array(self.scale, dtype=float)
        if self.kind == "covariance":
            return np.sqrt(np.einsum("ij,ij->i", self.chol, self.chol))
        return None

    def describe(self):
        """A few words for messages."""
        if self.kind == "scalar":
            return f"sigma={self.scale:g}"
        if self.kind == "diagonal":
            return f"sigma per {self.unit} ({self.scale.min():.3g} to {self.scale.max():.3g})"
        if self.kind == "covariance":
            return "a given covariance matrix"
        return "sigma estimated from the residual"


def noise_model(sigma, n, unit="observation"):
    """Validate ``sigma`` for ``n`` data values and return its :class:`NoiseModel`.

    A :class:`NoiseModel` of ``n`` values is returned as it is (validated once, its
    Cholesky factor computed once). ``unit`` names what one of the ``n`` values is, for
    the message (``"sensor"`` for a time series).

    Raises
    ------
    TypeError, ValueError
        Naming ``sigma`` and the shapes it may take.
    """
    if sigma is None:
        return NoiseModel("unknown", n)
    if isinstance(sigma, NoiseModel):
        if sigma.n != n:
            raise ValueError(f"`sigma` is a noise model of {sigma.n} values, the data have {n}")
        return sigma
    hint = (
        f"`sigma` is the noise of the data: a positive number, {n} positive standard "
        f"deviations (one per {unit}) or an ({n}, {n}) positive definite covariance"
    )
    if isinstance(sigma, bool):
        raise TypeError(f"{hint}; got {sigma!r}")
    if isinstance(sigma, numbers.Real):
        s = float(sigma)
        if not (np.isfinite(s) and s > 0):
            raise ValueError(f"{hint}; got {sigma!r}")
        return NoiseModel("scalar", n, s)
    try:
        a = np.asarray(sigma, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{hint}; got {type(sigma).__name__}") from None
    if a.ndim == 0:
        return noise_model(float(a), n, unit)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{hint}; `sigma` has non-finite entries")
    if a.shape == (n,):
        if np.any(a <= 0):
            raise ValueError(f"{hint}; entry {int(np.argmin(a))} is {a.min():g}")
        return NoiseModel("diagonal", n, a.copy())
    if a.shape == (n, n):
        if not np.allclose(a, a.T, rtol=1e-10, atol=0.0):
            raise ValueError(f"{hint}; the matrix given is not symmetric")
        try:
            L = np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            raise ValueError(f"{hint}; the matrix given is not positive definite") from None
        return NoiseModel("covariance", n, None, L)
    raise ValueError(f"{hint}; got shape {a.shape}")
