"""Sensor moments of a chaos solution and the Gaussian pseudo-likelihood of given moments
(paper Section 3.3, Eqs. stats, sens_stats, Lam, gradlam).

A stochastic Galerkin state :math:`\\Theta` predicts at the sensors the random values
:math:`v_i(\\omega) = \\mathcal M_{ij}\\Theta_{jk}\\Psi_k(\\omega)` with mean and variance
(Eq. stats)

.. math::

    \\mu_i = \\mathcal M_{ij}\\Theta_{jk}\\,\\mathbb E[\\Psi_k], \\qquad
    \\sigma_i^2 = \\mathcal M_{ij}\\Theta_{jk}\\mathcal M_{ip}\\Theta_{pq}
        \\mathbb E[\\Psi_k\\Psi_q] - \\mu_i^2 ;

replicated data ``v`` (C, D) are scored by the Gaussian negative log pseudo-likelihood
(Eq. Lam)

.. math::

    \\Lambda = \\sum_{i=1}^C\\sum_{j=1}^D \\tfrac12\\log 2\\pi\\sigma_i^2
        + \\frac{(v_{ij} - \\mu_i)^2}{2\\sigma_i^2}.
"""

from __future__ import annotations

import numpy as np

from ..._validation import as_dense_rows, as_finite_array
from ..statistics.verdict import DEFAULT_ALPHA, check_alpha, decide

__all__ = [
    "DegenerateVarianceError",
    "moment_verdict",
    "negative_log_pseudo_likelihood",
    "replicate_statistics",
    "sensor_moments",
]


class DegenerateVarianceError(ValueError):
    """The model predicts (numerically) zero variance at a sensor.

    The Gaussian pseudo-likelihood is then undefined (Eq. Lam divides by
    :math:`\\sigma_i^2`). No floor is applied silently: remove the sensor, or move it
    where the model output is random.
    """


# --------------------------------------------------------------------------------------
# moments and the pseudo-likelihood of given moments (Eqs. stats, sens_stats, Lam)
# --------------------------------------------------------------------------------------
def _centered_gram(E1, E2):
    """:math:`\\mathbb E[\\Psi\\Psi^T] - \\mathbb E[\\Psi]\\mathbb E[\\Psi]^T` (P, P).

    Computing :math:`\\sigma^2 = A\\,C_\\Psi A^T` with this matrix (exactly
    ``diag(0, 1, ..., 1)`` for the orthonormal basis) avoids the cancellation of
    :math:`\\mathbb E[v^2] - \\mu^2` in Eq. stats; the two are equal in exact arithmetic.
    """
    C = E2 - np.outer(E1, E1)
    return 0.5 * (C + C.T)


def sensor_moments(system, M_obs, Theta, dTheta=None):
    """Mean and variance of the sensor outputs and their derivatives (Eqs. stats, sens_stats).

    Parameters
    ----------
    system : GalerkinSystem
        Supplies the chaos moments ``E1`` (P,) and ``E2`` (P, P).
    M_obs : (C, N) array_like
        Sensor matrix :math:`\\mathcal M`.
    Theta : (N, P) array_like
        PCE coefficients.
    dTheta : (N, P, m) array_like, optional
        Derivatives of ``Theta`` in m parameters (forces or model parameters).

    Returns
    -------
    mu : (C,) ndarray
    var : (C,) ndarray
    dmu : (C, m) ndarray
        Only if ``dTheta`` is given: :math:`\\mathcal M\\,\\partial\\Theta\\,\\mathbb E[\\Psi]`.
    dvar : (C, m) ndarray
        Only if ``dTheta`` is given:
        :math:`2\\mathcal M_{ij}\\Theta_{jk}\\mathcal M_{ip}\\partial\\Theta_{pq}
        \\mathbb E[\\Psi_k\\Psi_q] - 2\\mu_i\\partial\\mu_i`.
    """
    M_obs = as_dense_rows("M_obs", M_obs, n_cols=system.N)
    Theta = as_finite_array("Theta", Theta, shape=system.shape)
    Cpsi = _centered_gram(system.E1, system.E2)
    A = M_obs @ Theta
    mu, var = _stats(A, system.E1, Cpsi)
    if dTheta is None:
        return mu, var
    dTheta = as_finite_array("dTheta", dTheta, shape=(system.N, system.P, None))
    dA = np.einsum("ij,jkm->ikm", M_obs, dTheta)
    return (mu, var, *_stats_derivative(A, dA, system.E1, Cpsi))


def _stats(A, E1, Cpsi):
    """Sensor mean and variance from the observed coefficients ``A = M_obs Theta`` (C, P)."""
    return A @ E1, np.einsum("ik,kq,iq->i", A, Cpsi, A)


def _stats_derivative(A, dA, E1, Cpsi):
    """Derivatives (C, m) of the sensor mean and variance for ``dA = M_obs dTheta`` (C, P, m)."""
    return np.einsum("ikm,k->im", dA, E1), 2.0 * np.einsum("ik,kq,iqm->im", A, Cpsi, dA)


def _check_data(v, C):
    v = as_finite_array("v", v, ndim=2)
    if v.shape[0] != C:
        raise ValueError(
            f"`v` must have shape (C, D) = ({C}, D), one row of replicates per sensor; "
            f"got {v.shape}"
        )
    if v.shape[1] < 2:
        raise ValueError(
            f"`v` needs at least 2 replicates per sensor to inform a variance, got D={v.shape[1]}"
        )
    return v


def _check_variance(var, mu, rtol):
    """Raise :class:`DegenerateVarianceError` where :math:`\\sigma_i^2` is lost in round-off."""
    second = var + mu**2
    bad = np.flatnonzero(~(var > rtol * second) | ~(var > 0))
    if bad.size:
        i = int(bad[0])
        raise DegenerateVarianceError(
            f"the model variance at sensor {i} is {var[i]:.3e} (mean {mu[i]:.3e}), numerically "
            "zero: the pseudo-likelihood (Eq. Lam) is undefined there. Remove that sensor or "
            "place it where the model output is random"
        )


def _nll_terms(mu, var, vbar, ss, D):
    """:math:`\\Lambda` and its first and second partials in (mu_i, var_i), per sensor.

    With :math:`S_i = \\sum_j (v_{ij} - \\mu_i)^2 = ss_i + D(\\bar v_i - \\mu_i)^2`,
    :math:`f = \\tfrac D2 \\log 2\\pi s + S/(2s)`.
    """
    r = vbar - mu
    S = ss + D * r**2
    f = 0.5 * D * np.log(2.0 * np.pi * var) + 0.5 * S / var
    f_mu = -D * r / var
    f_s = 0.5 * D / var - 0.5 * S / var**2
    f_mumu = D / var
    f_mus = D * r / var**2
    f_ss = -0.5 * D / var**2 + S / var**3
    return f, f_mu, f_s, f_mumu, f_mus, f_ss


def negative_log_pseudo_likelihood(mu, var, v, dmu=None, dvar=None):
    """The Gaussian negative log pseudo-likelihood of replicated data (Eqs. Lam, gradlam).

    Parameters
    ----------
    mu, var : (C,) array_like
        Model mean and (positive) variance at the sensors.
    v : (C, D) array_like
        ``D >= 2`` replicates per sensor.
    dmu, dvar : (C, m) array_like, optional
        Derivatives of the moments in m parameters.

    Returns
    -------
    value : float
    grad : (m,) ndarray
        Only if ``dmu`` and ``dvar`` are given (Eq. gradlam):
        :math:`\\sum_{ij} \\frac{\\partial_m\\sigma_i^2}{2\\sigma_i^2}
        - \\frac{(v_{ij}-\\mu_i)^2}{2\\sigma_i^4}\\partial_m\\sigma_i^2
        - \\frac{v_{ij}-\\mu_i}{\\sigma_i^2}\\partial_m\\mu_i`.

    Raises
    ------
    DegenerateVarianceError
        If a variance is not positive.
    """
    mu = as_finite_array("mu", mu, ndim=1)
    var = as_finite_array("var", var, shape=mu.shape)
    v = _check_data(v, mu.size)
    if np.any(var <= 0):
        i = int(np.flatnonzero(var <= 0)[0])
        raise DegenerateVarianceError(
            f"`var` must be positive; sensor {i} has variance {var[i]:.3e}. The "
            "pseudo-likelihood (Eq. Lam) is undefined for a deterministic output"
        )
    D = v.shape[1]
    vbar = v.mean(axis=1)
    ss = ((v - vbar[:, None]) ** 2).sum(axis=1)
    f, f_mu, f_s, *_ = _nll_terms(mu, var, vbar, ss, D)
    if dmu is None and dvar is None:
        return float(f.sum())
    if dmu is None or dvar is None:
        raise ValueError("pass both `dmu` and `dvar` for the gradient, or neither")
    dmu = as_finite_array("dmu", dmu, shape=(mu.size, None))
    dvar = as_finite_array("dvar", dvar, shape=dmu.shape)
    return float(f.sum()), f_mu @ dmu + f_s @ dvar


def replicate_statistics(v):
    """The statistics the pseudo-likelihood sees, and their sample covariance.

    :math:`\\Lambda` depends on the data only through the sensor means
    :math:`\\bar v_i` and the centred second moments :math:`m_i = \\frac1D\\sum_j
    (v_{ij} - \\bar v_i)^2`. Both are (asymptotically) means over the replicates of
    :math:`y_j = (v_{\\cdot j},\\ (v_{\\cdot j} - \\bar v)^2)`, whose covariance is
    estimated by the sample covariance of the :math:`y_j` divided by D (the sensors of one
    replicate may be correlated; replicates are independent).

    Parameters
    ----------
    v : (C, D) array_like
        Replicated data, ``D >= 2``.

    Returns
    -------
    w : (2C,) ndarray
        ``(vbar, m)``.
    Sigma_w : (2C, 2C) ndarray
        Sample covariance of ``w``.
    """
    v = as_finite_array("v", v, ndim=2)
    if v.shape[1] < 2:
        raise ValueError(
            f"`v` needs at least 2 replicates per sensor for a sample covariance, got "
            f"D={v.shape[1]}"
        )
    D = v.shape[1]
    vbar = v.mean(axis=1)
    dev = v - vbar[:, None]
    y = np.vstack([v, dev**2])  # (2C, D): one column per replicate
    return np.concatenate([vbar, (dev**2).mean(axis=1)]), np.atleast_2d(np.cov(y, ddof=1)) / D


def moment_verdict(mu, var, v, alpha=DEFAULT_ALPHA, at_bound=()):
    """Whether the fitted model's sensor means agree with the replicated data.

    z-scores :math:`z_i = (\\bar v_i - \\mu_i)/\\sqrt{\\sigma_i^2/D}` of the sample means
    against the model's moments (Eq. stats), combined by Bonferroni into one p-value
    :math:`\\min(1, C\\,\\min_i p_i)` (valid however the sensors of a replicate are
    correlated), judged at size ``alpha`` by the one rule of
    :func:`~ecfm_uq.inverse.statistics.verdict.decide`.

    Parameters
    ----------
    mu, var : (C,) array_like
        Model mean and variance at the sensors.
    v : (C, D) array_like
        Replicated data.
    alpha : float
    at_bound : sequence of (int, str)
        The estimate's parameters at a bound
        (:func:`~ecfm_uq.inverse.core.convergence.at_bound`): reported as an identifiability
        finding, not folded into the test.

    Returns
    -------
    Verdict
        ``details``: ``z`` (C,), ``z_limit`` (the Bonferroni quantile
        :math:`z_{1-\\alpha/(2C)}`), ``peak_sensor_index``.
    """
    from scipy import stats

    mu = as_finite_array("mu", mu, ndim=1)
    var = as_finite_array("var", var, shape=mu.shape)
    v = _check_data(v, mu.size)
    alpha = check_alpha(alpha)
    C, D = v.shape
    z = (v.mean(axis=1) - mu) / np.sqrt(var / D)
    limit = float(stats.norm.ppf(1 - alpha / (2 * C)))
    peak = int(np.argmax(np.abs(z)))
    p_value = min(1.0, C * 2.0 * float(stats.norm.sf(abs(z[peak]))))
    parts = [
        f"largest |z| of the sensor means {abs(z[peak]):.3g} at sensor {peak} "
        f"({'<=' if abs(z[peak]) <= limit else '>'} {limit:.3g}; Bonferroni p = "
        f"{p_value:.3g}, size {alpha:g})"
    ]
    return decide(
        "moments z (Bonferroni)", p_value, alpha, parts, statistic=abs(z[peak]), at_bound=at_bound,
        details={"z": z, "z_limit": limit, "peak_sensor_index": peak},
    )  # fmt: skip
