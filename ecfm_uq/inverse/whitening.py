"""A Galerkin problem whose ``sigma`` is an array, written once for whitened data.

With the sensors' noise covariance :math:`\\Sigma = LL^T` (or standard deviations
:math:`\\sigma_i`) and :math:`W = L^{-1}` (or :math:`\\mathrm{diag}(1/\\sigma_i)`,
:mod:`.noise_model`), the whitened residual of the sensors is

.. math::

    W(\\mathcal M\\theta - v) = (W\\mathcal M)\\,\\theta - Wv ,

so the problem with sensor matrix :math:`W\\mathcal M`, data :math:`Wv` (every time row
:math:`Wv_i` of a time series) and ``sigma = 1`` *is* the fit with ``sigma`` on the
original data, for every formulation that is a function of the sensors' residual:

* ``"standard"``: least squares on :math:`W(\\mathcal M\\theta - v)` with the Jacobian
  :math:`W\\mathcal M\\,\\partial\\theta/\\partial\\epsilon`, Gauss-Newton standard errors
  :math:`((WJ)^T WJ)^{-1}`, the chi-squared verdict on the whitened residual, and the
  profile likelihood of :math:`\\tfrac12\\|W r\\|^2` (Bates & Watts 1988, Sec. 1.3;
  scipy's ``curve_fit(sigma=..., absolute_sigma=True)``).
* ``"ecfm"`` (exact match): :math:`W\\mathcal M\\theta = Wv` has the solutions of
  :math:`\\mathcal M\\theta = v` (:math:`W` is invertible), so the state, the forces and
  the estimate are those of the unwhitened problem; ``sigma`` enters only the estimate's
  uncertainty (data covariance :math:`I` for :math:`Wv` is :math:`\\Sigma` for :math:`v`:
  the same delta method) and the verdict (chi-squared on the whitened unforced residual).
* ``"ecfm-random"``: :math:`I + \\tau^2(WA)(WA)^T = W(\\Sigma + \\tau^2AA^T)W^T`, so the
  marginal likelihood is that of the data covariance :math:`\\Sigma + \\tau^2 AA^T` (up to
  the constant :math:`\\log\\det W`) and the restricted likelihood's error contrasts are
  those of generalized least squares; the forces' posterior mean
  :math:`\\tau^2A^T(\\Sigma + \\tau^2AA^T)^{-1}r` is unchanged by the whitening.

For a :class:`~.dynamic.DynamicInverseProblem`, ``sigma`` describes the ``C`` sensors:
one number, one standard deviation per sensor ``(C,)`` or a covariance over the sensors
``(C, C)``, the same at every time, readings at different times independent. A
``(C, C)`` array is always the covariance (variances on its diagonal), also when
``n_steps == C``; a sigma per reading ``(n_steps, C)`` is refused by
:func:`~ecfm_uq.inverse.fit` (noise that changes with time: fit the readings as a
:class:`~.model_problem.ModelProblem`, whose ``sigma`` is one per observation). Why not
here: the whitening would then change with time, which no single sensor matrix
:math:`W\\mathcal M` expresses.

The estimate's derivative in the data (``uncertainty.jacobian``) is returned in the units
of the data the user gave: :func:`jacobian_in_data_units`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["jacobian_in_data_units", "whitened_problem"]


def _whiten_rows(M, noise):
    """:math:`W\\mathcal M` for a dense or sparse sensor matrix (C, N)."""
    if sp.issparse(M):
        if noise.kind == "diagonal":
            return sp.csr_matrix(sp.diags(1.0 / noise.scale) @ M)
        return np.asarray((M.T @ noise.matrix().T).T)
    return noise.whiten(M)


def whitened_problem(problem, noise):
    """The same problem with its sensor matrix and data whitened by ``noise``.

    Parameters
    ----------
    problem : SteadyProblem or DynamicInverseProblem
    noise : NoiseModel
        Of the ``C`` sensors (:func:`~.noise_model.noise_model`), kind ``"diagonal"`` or
        ``"covariance"``.

    Returns
    -------
    SteadyProblem or DynamicInverseProblem
        A copy (:meth:`~.interface.InverseProblem.with_data`): sensor matrix :math:`W\\mathcal M`, data :math:`Wv` (``V`` rows
        :math:`Wv_i`), the rest shared. Fit it with ``sigma=1``.
    """
    data = problem.data
    # a time series (rows = times) is whitened time by time, one reading vector per row
    white = noise.whiten(data.T).T if data.ndim == 2 else noise.whiten(data)
    new = problem.with_data(white)  # the problems' one copy (it starts cold)
    new.M_obs = _whiten_rows(problem.M_obs, noise)
    return new


def jacobian_in_data_units(D, noise):
    """:math:`d\\hat\\epsilon/dv = (d\\hat\\epsilon/d(Wv))\\,W`, time by time.

    Parameters
    ----------
    D : (n_eps, n_times C) ndarray or None
        The derivative in the whitened data (readings stacked time by time).
    noise : NoiseModel
        Of the ``C`` sensors.
    """
    if D is None:
        return None
    D = np.asarray(D, dtype=float)
    return noise.pull_back(D.reshape(-1, noise.n)).reshape(D.shape)
