"""Uncertainty of an estimate by implicit differentiation and the delta method.

An estimate eps_hat(v) is defined by an optimality condition g(eps, v) = 0 (the
standard least-squares gradient, the ECFM conditions, the pseudo-likelihood
conditions). Implicit differentiation gives

.. math::

    \\frac{d\\hat\\varepsilon}{dv} = -\\Big(\\frac{\\partial g}{\\partial\\varepsilon}\\Big)^{-1}
    \\frac{\\partial g}{\\partial v},
    \\qquad
    \\operatorname{Cov}\\hat\\varepsilon \\approx \\frac{d\\hat\\varepsilon}{dv}\\,
    \\Sigma_v\\,\\frac{d\\hat\\varepsilon}{dv}^T .

For the standard Gaussian formulation of a linear model (g = J^T (J eps - v)) this is
the Gauss-Newton / Laplace covariance sigma^2 (J^T J)^{-1}; for a nonlinear model the
two differ: dg/deps is then the full Hessian J^T J + sum_c r_c d2(M_obs theta)_c/deps2,
while Gauss-Newton drops the residual-curvature term.

The steady, noisy SLSQP and pseudo-likelihood fits (:func:`~ecfm_uq.inverse.fit` of a
:class:`~ecfm_uq.inverse.SteadyProblem`: standard, exact-force ECFM, ``"all-at-once"``
and ``"noisy-ecfm"``; of a :class:`~ecfm_uq.inverse.ReplicatedProblem`) compute their
covariance (``result.uncertainty.cov``) through :func:`implicit_covariance`; only the
optimality condition and the data covariance differ. The dynamic (Adam) fits do not carry
one yet.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..._validation import all_finite, as_finite_array
from ...errors import ConvergenceError, NonIdentifiableError
from ..core.convergence import scaled_svd
from ..core.finite_differences import fd_jacobian
from ..core.result import Uncertainty, interval_quantile

#: an information matrix whose smallest/largest singular value is below this is singular
#: (its finite-difference entries carry ~1e-10 relative round-off)
IDENTIFIABILITY_RCOND = 1e-9


def estimate_jacobian(dg_deps, dg_dv):
    """Implicit derivative d eps_hat/dv of an estimate defined by g(eps, v) = 0.

    Parameters
    ----------
    dg_deps : (n_eps, n_eps) ndarray
        Derivative of the optimality condition with respect to eps at the estimate.
    dg_dv : (n_eps, C) ndarray
        Derivative of the optimality condition with respect to the data.

    Returns
    -------
    (n_eps, C) ndarray
        ``-(dg/deps)^{-1} dg/dv``.
    """
    A = as_finite_array("dg_deps", dg_deps, ndim=2)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"`dg_deps` must be square, got {A.shape}")
    B = as_finite_array("dg_dv", dg_dv, ndim=2)
    if B.shape[0] != A.shape[0]:
        raise ValueError(f"`dg_dv` must have {A.shape[0]} rows (n_eps), got {B.shape[0]}")
    check_identifiable(A)
    return -np.linalg.solve(A, B)


def parameter_combination(u, names=None, tol=1e-3):
    """``"0.707*eps[0] - 0.707*eps[1]"``: a direction in parameter space as text.

    Components smaller than ``tol`` times the largest are left out.
    """
    u = np.asarray(u, dtype=float).ravel()
    if names is None:
        names = [f"eps[{k}]" for k in range(u.size)]
    # a stable sign: the first of the (near-)largest components positive
    k0 = int(np.flatnonzero(np.abs(u) >= (1 - 1e-6) * np.abs(u).max())[0])
    u = u * np.sign(u[k0])
    parts = []
    for k in np.flatnonzero(np.abs(u) >= tol * np.abs(u).max()):
        c = u[k]
        sign = "-" if c < 0 else "+"
        parts.append(f"{sign} {abs(c):.3g}*{names[k]}")
    text = " ".join(parts)
    return text[2:] if text.startswith("+ ") else text


def check_identifiable(info, rcond=IDENTIFIABILITY_RCOND, names=None):
    """Raise :class:`~ecfm_uq.errors.NonIdentifiableError` if ``info`` is singular.

    Parameters
    ----------
    info : (n_eps, n_eps) ndarray
        Information matrix: the derivative of an estimate's optimality condition in eps
        (for least squares the Hessian of the misfit, ``J^T J`` in the linear case).
    rcond : float
        Singular when ``s_min <= rcond * s_max`` for ``info`` scaled to unit diagonal
        (:math:`D^{-1}AD^{-1}`, :math:`D = \\sqrt{|\\operatorname{diag} A|}`: unit-free in
        the parameters) when ``info`` is symmetric with a positive diagonal.
    names : list of str, optional
        Parameter names for the message (default ``eps[k]``).

    Raises
    ------
    NonIdentifiableError
        Naming the combination of parameters (the right singular vector of the smallest
        singular value) the data do not determine.
    """
    A = as_finite_array("info", info, ndim=2)
    # the test is on the matrix scaled to unit diagonal, so that it does not depend on
    # the parameters' units (a parameter of size 1e-4 beside one of size 1e2 is not a
    # singularity); a zero diagonal entry is a parameter the data do not see at all
    # (for a symmetric matrix with a positive diagonal, an information matrix; a general
    # one, e.g. a KKT matrix with its zero blocks, is tested as it is)
    d = np.sqrt(np.abs(np.diag(A))) if A.shape[0] == A.shape[1] else np.zeros(0)
    symmetric = d.size and np.allclose(A, A.T, rtol=1e-6, atol=0)
    if symmetric and np.all(np.diag(A) > 0):
        As = A / np.outer(d, d)
    else:
        As, d = A, np.ones(A.shape[1])
    _, s, Vt = np.linalg.svd(As)
    if s[0] > 0 and s[-1] > rcond * s[0]:
        return
    ratio = s[-1] / s[0] if s[0] > 0 else 0.0
    u = Vt[-1] / d
    u = u / np.linalg.norm(u)
    raise NonIdentifiableError(
        f"the information matrix is singular (smallest/largest singular value {ratio:.1e}): "
        f"the data do not determine the parameter combination {parameter_combination(u, names)}; "
        "fix one of these parameters, reparametrize, or add sensors that see it",
        null_vector=u,
    )


#: a sensitivity Jacobian J (exact, not differenced) whose columns scaled to unit norm
#: have smallest/largest singular value below this does not determine eps (J^T J would
#: be singular to about its square, 1e-16: round-off)
JACOBIAN_RCOND = 1e-8


def least_squares_jacobian(J, names=None, rcond=JACOBIAN_RCOND):
    """The estimate's derivative in the data, :math:`d\\hat\\epsilon/dv = J^+ =
    (J^TJ)^{-1}J^T`, of a least-squares fit with residual Jacobian ``J`` (Gauss-Newton).

    Computed by the SVD of ``J`` with its columns scaled to unit norm, so the accuracy
    follows the conditioning of ``J`` (not of :math:`J^TJ`, its square) and does not
    depend on the parameters' units.

    Parameters
    ----------
    J : (C, n_eps) ndarray
    names : list of str, optional
    rcond : float

    Returns
    -------
    (n_eps, C) ndarray

    Raises
    ------
    NonIdentifiableError
        When the scaled ``J`` is singular to ``rcond``, naming the combination.
    """
    J = as_finite_array("J", J, ndim=2)
    d, U, sv, Vt = scaled_svd(J)  # the status test's factorization when it judged this J
    if U is None:
        k = int(np.flatnonzero(d == 0)[0])
        u = np.eye(J.shape[1])[k]
        raise NonIdentifiableError(
            f"the data do not see the parameter {parameter_combination(u, names)} at all "
            "(its sensitivity is zero); fix it or add sensors that see it",
            null_vector=u,
        )
    if sv[-1] <= rcond * sv[0]:
        u = Vt[-1] / d
        u = u / np.linalg.norm(u)
        raise NonIdentifiableError(
            f"the sensitivity matrix is singular (smallest/largest singular value of its "
            f"scaled columns {sv[-1] / sv[0]:.1e}): the data do not determine the parameter "
            f"combination {parameter_combination(u, names)}; fix one of these parameters, "
            "reparametrize, or add sensors that see it",
            null_vector=u,
        )
    return (Vt.T / sv) @ U.T / d[:, None]


def delta_method_covariance(deps_dv, Sigma_v):
    """Delta-method covariance ``(d eps_hat/dv) Sigma_v (d eps_hat/dv)^T``.

    Parameters
    ----------
    deps_dv : (n_eps, C) ndarray
    Sigma_v : float or (C,) or (C, C) ndarray
        Data covariance: a variance sigma^2, per-sensor variances, or a full matrix.

    Returns
    -------
    (n_eps, n_eps) ndarray
    """
    D = as_finite_array("deps_dv", deps_dv, ndim=2)
    C = D.shape[1]
    if type(Sigma_v) is float and Sigma_v > 0 and math.isfinite(Sigma_v):
        # one variance, as a fit passes it: the branch below without the array round trip
        cov = Sigma_v * D @ D.T
        return 0.5 * (cov + cov.T)
    S = np.asarray(Sigma_v, dtype=float)
    if not all_finite(S):
        raise ValueError("`Sigma_v` has non-finite entries")
    if S.ndim == 0:
        if S <= 0:
            raise ValueError(f"`Sigma_v` must be a positive variance, got {float(S)}")
        cov = float(S) * D @ D.T
    elif S.ndim == 1:
        if S.shape != (C,) or np.any(S <= 0):
            raise ValueError(f"`Sigma_v` as variances must be ({C},) and positive")
        cov = (D * S) @ D.T
    else:
        S = as_finite_array("Sigma_v", S, shape=(C, C))
        cov = D @ S @ D.T
    return 0.5 * (cov + cov.T)


def gauss_newton_covariance(J, sigma2):
    """Gauss-Newton / Laplace covariance ``sigma^2 (J^T J)^{-1}``.

    Parameters
    ----------
    J : (C, n_eps) ndarray
        Sensitivity of the predicted measurements to eps.
    sigma2 : float
        Noise variance.
    """
    J = as_finite_array("J", J, ndim=2)
    if not sigma2 > 0:
        raise ValueError(f"`sigma2` must be positive, got {sigma2}")
    check_identifiable(J.T @ J)
    return sigma2 * np.linalg.inv(J.T @ J)


def residual_variance(r, n_eps):
    """Residual estimate s^2 = ||r||^2 / (C - n_eps) of the noise variance."""
    r = np.asarray(r, dtype=float).ravel()
    if r.size <= n_eps:
        raise ValueError(f"need more data ({r.size}) than parameters ({n_eps}) to estimate sigma")
    return float(r @ r) / (r.size - n_eps)


@functools.lru_cache(maxsize=64)
def _quantile(level, dof):
    """:func:`~ecfm_uq.inverse.core.result.interval_quantile`, remembered (a Student-t
    quantile is an iterative inverse: tens of microseconds, as much as a small fit's
    uncertainty)."""
    return interval_quantile(level, dof)


def confidence_intervals(eps, eps_cov, level=0.95, dof=None):
    """Standard errors and ``level`` intervals: normal quantile, or Student-t with
    ``dof`` degrees of freedom when sigma was estimated from the residual (C - n_eps).

    Returns
    -------
    stderr : (n_eps,) ndarray
    intervals : (n_eps, 2) ndarray
    """
    if not 0 < level < 1:
        raise ValueError(f"`level` must lie in (0, 1), got {level}")
    eps = np.asarray(eps, dtype=float).ravel()
    cov = as_finite_array("eps_cov", eps_cov, shape=(eps.size, eps.size))
    se = np.sqrt(np.maximum(cov.diagonal(), 0.0))  # clip at 0: round-off negatives
    z = _quantile(level, dof)
    ci = np.empty((eps.size, 2))
    np.subtract(eps, z * se, out=ci[:, 0])
    np.add(eps, z * se, out=ci[:, 1])
    return se, ci


def implicit_covariance(grad, eps, v, Sigma_v, rel_step=1e-6, stencil=2):
    """Delta-method covariance of an estimate defined by ``grad(eps, v) = 0``.

    Second derivatives are central finite differences of the analytic gradient
    ``grad`` (exact ones are not available for the ECFM conditions); the step is
    ``rel_step * max(|x|, 1)`` per coordinate. ``stencil=4`` uses the fourth-order
    central difference (twice the evaluations): for a gradient that is itself the
    output of an iterative solve, a larger step with O(h^4) truncation keeps its
    solver noise out of the covariance.

    Parameters
    ----------
    grad : callable ``(eps (n_eps,), v (C,)) -> (n_eps,)``
    eps : (n_eps,) ndarray
        The estimate.
    v : (C,) ndarray
        The data it was fitted to.
    Sigma_v : float or (C,) or (C, C)
        Data covariance.
    rel_step : float
    stencil : {2, 4}

    Returns
    -------
    eps_cov : (n_eps, n_eps) ndarray
    deps_dv : (n_eps, C) ndarray
    """
    if stencil not in (2, 4):
        raise ValueError(
            f"`stencil` must be 2 or 4 (points of the central difference), got {stencil!r}"
        )
    eps = np.asarray(eps, dtype=float)
    v = np.asarray(v, dtype=float)

    def fd(f, x):
        return _fd_jacobian(f, x, rel_step, stencil)

    dg_deps = fd(lambda e: grad(e, v), eps)
    dg_deps = 0.5 * (dg_deps + dg_deps.T)
    dg_dv = fd(lambda w: grad(eps, w), v)
    D = estimate_jacobian(dg_deps, dg_dv)
    return delta_method_covariance(D, Sigma_v), D


def estimate_uncertainty(
    grad,
    eps,
    data,
    Sigma,
    noise_model,
    *,
    dof=None,
    block=None,
    hint=None,
    hessian=None,
    dg_dv=None,
    deps_dv=None,
    names=None,
    data_noise=None,
    **fd_options,
):
    """The :class:`~ecfm_uq.inverse.Uncertainty` of an estimate, or why there is none.

    Every fit reports its uncertainty through here: :func:`implicit_covariance` of the
    estimate defined by ``grad(eps, data) = 0``, then :func:`confidence_intervals`.

    Parameters
    ----------
    grad : callable ``(x, data) -> (n,)``
        The optimality condition.
    eps : (n,) ndarray
        Where it holds (the estimate, or a larger vector holding it, see ``block``).
    data : (m,) ndarray
    Sigma : float, (m,) or (m, m)
        Covariance of ``data``.
    noise_model : str
        Recorded as ``noise_model`` (``"known"``, ``"estimated"``, ``"replicates"``).
    dof : int, optional
        Student-t degrees of freedom of the intervals (normal quantile if None).
    block : slice, optional
        The parameters' part of ``x`` when the condition has more unknowns (KKT
        multipliers, states).
    hint : str, optional
        Added to the message when the data do not determine the estimate.
    hessian : (n, n) ndarray, optional
        The condition's derivative in ``x`` to use instead of differencing ``grad``:
        :math:`J^TJ` for the Gauss-Newton convention of a sum of squares (labelled
        ``method="gauss-newton"``; without it the full Hessian by finite
        differences, the sandwich :math:`H^{-1}J^TJH^{-1}s^2` for least squares,
        labelled ``"implicit"``).
    dg_dv : (n, m) ndarray, optional
        The condition's derivative in the data, when known exactly (else differenced).
    deps_dv : (n, m) ndarray, optional
        The estimate's derivative in the data itself, when known (e.g.
        :func:`least_squares_jacobian`, labelled ``"gauss-newton"``); then ``grad``,
        ``hessian`` and ``dg_dv`` are not used.
    names : list of str, optional
        The parameter names, recorded as ``names`` (for
        :meth:`~ecfm_uq.inverse.Uncertainty.to_inputs`).
    data_noise : NoiseModel, optional
        A known noise model the data were whitened by (``data`` is :math:`Wv`,
        ``Sigma`` 1): the recorded ``jacobian`` is then the estimate's derivative in
        :math:`v` (``data_noise.pull_back``) and ``sigma`` the noise as given
        (``data_noise.std()``).
    **fd_options
        ``rel_step``, ``stencil`` of :func:`implicit_covariance`.

    Returns
    -------
    Uncertainty
        ``cov``, ``stderr``, ``intervals``, ``noise_model``, ``dof``, ``jacobian``,
        ``method``, ``eps`` and ``sigma`` (:math:`\\sqrt{\\Sigma}` for one noise level,
        known or estimated; else ``None``); or ``success=False`` with the ``message`` why when the covariance
        cannot be computed (never NaN).
    """
    try:
        if deps_dv is not None:
            D = np.asarray(deps_dv, dtype=float)
            cov = delta_method_covariance(D, Sigma)
        elif hessian is None and dg_dv is None:
            cov, D = implicit_covariance(grad, eps, data, Sigma, **fd_options)
        else:
            x = np.asarray(eps, dtype=float)
            w = np.asarray(data, dtype=float)
            A = np.asarray(hessian, dtype=float) if hessian is not None else None
            B = np.asarray(dg_dv, dtype=float) if dg_dv is not None else None
            if A is None or B is None:
                if A is None:
                    A = _fd_jacobian(lambda e: grad(e, w), x, **fd_options)
                    A = 0.5 * (A + A.T)
                if B is None:
                    B = _fd_jacobian(lambda v: grad(x, v), w, **fd_options)
            D = estimate_jacobian(A, B)
            cov = delta_method_covariance(D, Sigma)
    except NonIdentifiableError as e:
        where = f" ({hint})" if hint else ""
        return Uncertainty.failed(f"uncertainty not computed{where}: {e}")
    except (ConvergenceError, ValueError) as e:
        return Uncertainty.failed(f"uncertainty not computed: {e}")
    eps = np.asarray(eps, dtype=float)
    if block is not None:
        cov, D, eps = cov[block, block], D[block], eps[block]
    se, ci = confidence_intervals(eps, cov, dof=dof)
    one_sigma = noise_model in ("known", "estimated") and (
        type(Sigma) is float or np.ndim(Sigma) == 0
    )
    if data_noise is not None:  # d eps/d(W v) as d eps/dv, and the noise as given
        return Uncertainty(
            True, cov=cov, stderr=se, intervals=ci,
            method="implicit" if hessian is None and deps_dv is None else "gauss-newton",
            noise_model=noise_model, dof=dof, jacobian=data_noise.pull_back(D),
            sigma=data_noise.std(), eps=eps.copy(), names=names,
        )  # fmt: skip
    return Uncertainty(
        True,
        cov=cov,
        stderr=se,
        intervals=ci,
        method="implicit" if hessian is None and deps_dv is None else "gauss-newton",
        noise_model=noise_model,
        dof=dof,
        jacobian=D,
        sigma=(math.sqrt(Sigma) if type(Sigma) is float else float(np.sqrt(Sigma)))
        if one_sigma
        else None,
        eps=eps.copy(),
        names=names,
    )


def _fd_jacobian(f, x, rel_step=1e-6, stencil=2):
    """Central-difference Jacobian of ``f`` at ``x`` (the stencil of
    :func:`implicit_covariance`: 2 or 4 points, steps ``rel_step * max(|x|, 1)``)."""
    x = np.asarray(x, dtype=float)
    return fd_jacobian(
        f, x, method="3-point" if stencil == 2 else "5-point",
        steps=rel_step * np.maximum(np.abs(x), 1.0),
    )  # fmt: skip
