"""A Galerkin problem whose ``sigma`` is an array, written once for whitened data.

With the sensors' noise covariance :math:`\\Sigma = LL^T` (or standard deviations
:math:`\\sigma_i`) and :math:`W = L^{-1}` (or :math:`\\mathrm{diag}(1/\\sigma_i)`,
:mod:`ecfm_uq.inverse.problems.noise_model`), the whitened residual of the sensors is

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

For a :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem`
(:func:`dynamic_noise_model`), readings at different times are independent and ``sigma`` is

* one number, one standard deviation per sensor ``(C,)`` or a covariance over the
  sensors ``(C, C)``, the same at every time: :math:`W` as above, every time row
  :math:`Wv_i`;
* one standard deviation per reading ``(n_steps, C)``, the shape of the readings fitted
  ``V[1:]`` (noise that changes with time; flattened time by time, ``(n_steps * C,)``, is
  the same): reading :math:`(i, c)` has standard deviation :math:`\\sigma_{ic}` and
  :math:`W_i = \\mathrm{diag}(1/\\sigma_{i\\cdot})` changes with the time. No single sensor
  matrix :math:`W\\mathcal M` expresses that, so the whitened copy keeps :math:`\\mathcal M`
  and carries the per-reading standard deviations
  (:attr:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem.reading_sigma`): its data
  are :math:`v_{ic}/\\sigma_{ic}` and its predicted readings :math:`(\\mathcal
  M\\theta_i)_c/\\sigma_{ic}`, where they and their derivatives (forward sensitivities, the
  adjoint's load) are formed
  (:meth:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem.predictions`); the ECFM
  constraint is :math:`\\mathcal M\\theta_i = v_i` (the same solutions), in the data's
  units.

Which is which, by shape (``C`` sensors, ``n_steps`` readings each): ``(C, C)`` is always
the covariance (variances on its diagonal), also when ``n_steps == C``, where a sigma per
reading must then be given flattened, ``(n_steps * C,)``; ``(C,)`` is per sensor (when
``n_steps == 1`` it is also per reading: the same thing); ``(n_steps + 1, C)``, the shape
of ``V`` with its unfitted initial row, is refused (pass ``sigma[1:]``), as is any other
shape, naming ``sigma`` and the shapes it may take.

The estimate's derivative in the data (``uncertainty.jacobian``) is returned in the units
of the data the user gave: :func:`jacobian_in_data_units`.
"""

from __future__ import annotations

import numbers

import numpy as np
import scipy.sparse as sp

from .noise_model import NoiseModel, noise_model

__all__ = ["dynamic_noise_model", "jacobian_in_data_units", "whitened_problem"]

#: what one of the ``C`` values of a sensor sigma is, for messages
SENSOR_UNIT = "sensor, the same at every time"


def dynamic_noise_model(sigma, n_steps, n_sensors):
    """``sigma`` of a time series of ``n_steps`` readings of ``n_sensors`` sensors,
    validated: ``None``/a number/``(C,)``/``(C, C)`` the sensors' noise model (``n = C``),
    ``(n_steps, C)`` (or ``(n_steps * C,)``) the readings' (``n = n_steps * C``, kind
    ``"diagonal"``, time by time); the rules are the module's.

    Raises
    ------
    TypeError, ValueError
        Naming ``sigma`` and the shapes it may take.
    """
    P, C = int(n_steps), int(n_sensors)
    if isinstance(sigma, NoiseModel):
        if sigma.n == P * C and sigma.kind != "diagonal":
            raise ValueError(
                "`sigma` over the readings must be one standard deviation per reading "
                "(independent times), not a noise model of kind " + repr(sigma.kind)
            )
        return sigma if sigma.n == P * C else noise_model(sigma, C, SENSOR_UNIT)
    if sigma is None or isinstance(sigma, bool | numbers.Real) or np.ndim(sigma) == 0:
        return noise_model(sigma, C, SENSOR_UNIT)
    shapes = (
        f"`sigma` of a time series of {P} readings of {C} sensors is a positive number, "
        f"({C},) one standard deviation per sensor or ({C}, {C}) a covariance over the "
        f"sensors (the same at every time), or ({P}, {C}) one standard deviation per "
        f"reading, the rows of V[1:] (flattened: ({P * C},))"
    )
    try:
        a = np.asarray(sigma, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{shapes}; got {type(sigma).__name__}") from None
    if a.shape in ((C,), (C, C)):
        try:
            return noise_model(a, C, SENSOR_UNIT)
        except ValueError as e:
            if a.ndim == 2 and P == C:
                raise ValueError(
                    f"{e}; a ({C}, {C}) `sigma` is the covariance over the sensors, also "
                    f"when n_steps == C: give a sigma per reading flattened, ({P * C},)"
                ) from None
            raise
    if a.shape == (P + 1, C):
        raise ValueError(
            f"{shapes}; got shape {a.shape}, that of V with its initial row, which no "
            "formulation fits: pass sigma[1:]"
        )
    if a.shape not in ((P, C), (P * C,)):
        raise ValueError(f"{shapes}; got shape {a.shape}")
    a = a.reshape(P, C)
    bad = ~(np.isfinite(a) & (a > 0))
    if bad.any():
        i, c = np.argwhere(bad)[0]
        raise ValueError(
            f"{shapes}; the standard deviation of reading ({i}, {c}) (V[{i + 1}, {c}]) is "
            f"{a[i, c]:g}, not a positive finite number"
        )
    return NoiseModel("diagonal", P * C, a.ravel().copy(), unit="reading")


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
        Of the ``C`` sensors (:func:`~ecfm_uq.inverse.problems.noise_model.noise_model`),
        kind ``"diagonal"`` or ``"covariance"``; or, for a time series, of its ``n_steps *
        C`` readings (kind ``"diagonal"``, :func:`dynamic_noise_model`).

    Returns
    -------
    SteadyProblem or DynamicInverseProblem
        A copy (:meth:`~ecfm_uq.inverse.problems.interface.InverseProblem.with_data`): sensor matrix
        :math:`W\\mathcal M`, data :math:`Wv` (``V`` rows :math:`Wv_i`), the rest shared;
        for a sigma per reading the sensor matrix unchanged, data
        :math:`v_{ic}/\\sigma_{ic}` and ``reading_sigma`` set (the module's text). Fit it
        with ``sigma=1``.
    """
    data = problem.data
    if data.ndim == 2 and noise.n != problem.n_sensors:  # a sigma per reading
        sigma = np.vstack([np.ones((1, data.shape[1])), noise.scale.reshape(-1, data.shape[1])])
        new = problem.with_data(data / sigma)
        new.reading_sigma = sigma  # where the predicted readings are formed
        return new
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
        Of the ``C`` sensors, or of all the readings (a sigma per reading).
    """
    if D is None:
        return None
    D = np.asarray(D, dtype=float)
    return noise.pull_back(D.reshape(-1, noise.n)).reshape(D.shape)
