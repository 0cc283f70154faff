"""The negative log-likelihood of a fit as a function of :math:`\\epsilon`.

A fit "has a likelihood" when its objective is (up to a constant and a positive factor) the
negative log-likelihood of the data under a stated noise model. Each problem kind says
so once, in its ``log_likelihood(formulation, sigma)`` method, with the builders here
(:func:`gaussian_likelihood` for a whitened residual, :func:`least_squares_likelihood`
for a sum of squares and its gradient), returning a :class:`LogLikelihood` or the reason
there is none; the profile-likelihood intervals and likelihood-ratio tests of
:mod:`ecfm_uq.inverse.statistics.profile` are built on it.

=====================  ==================  ==============================================
problem                formulation         :math:`\\ell(\\epsilon)` (negative log-likelihood)
=====================  ==================  ==============================================
SteadyProblem          ``"standard"``      :math:`\\|r\\|^2/(2\\sigma^2)` with ``sigma``;
                                           :math:`\\tfrac n2\\log\\|r\\|^2` (σ profiled out)
DynamicInverseProblem  ``"standard"``      the same over the ``n = P C`` readings
ReplicatedProblem      ``"standard"``      :math:`\\Lambda(\\epsilon, 0)` (Eq. Lam)
=====================  ==================  ==============================================

:math:`r = \\mathcal M\\,\\mathbb E[\\theta(\\epsilon)] - v` are the residuals at the sensors.
With :math:`\\sigma` unknown it is profiled out, :math:`\\hat\\sigma^2 = \\|r\\|^2/n`, which
leaves :math:`\\tfrac n2\\log\\|r\\|^2` up to a constant (the usual profile likelihood of a
Gaussian regression). The paper's ECFM objective :math:`\\tfrac12\\|\\lambda\\|^2` and the
noisy-ECFM / penalty formulations are not likelihoods of the data: their results carry
no :class:`LogLikelihood` and :func:`~ecfm_uq.inverse.profile_intervals` says so.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = [
    "LogLikelihood",
    "gaussian_likelihood",
    "least_squares_likelihood",
    "no_likelihood",
    "remember_last_point",
]


@dataclass(frozen=True)
class LogLikelihood:
    """:math:`\\ell(\\epsilon)`, a negative log-likelihood up to an additive constant.

    Attributes
    ----------
    evaluate : callable
        ``evaluate(eps) -> (value, gradient)``; raises the model's own errors
        (``ConvergenceError``, ``ModelEvaluationError``) where the model cannot be solved.
    n_eps : int
    n_data : int
        Number of data values the likelihood is built on.
    noise : str
        ``"known sigma"``, ``"profiled sigma"`` or ``"replicated"``.
    description : str
        One line for messages and plots.
    exact_gradient : bool
        Whether ``evaluate``'s gradient is exact (else finite differences: optimizers on it
        stop at a correspondingly looser tolerance).
    """

    evaluate: Callable
    n_eps: int
    n_data: int
    noise: str
    description: str
    exact_gradient: bool = True  # False: finite differences, accurate to about 1e-6
    value_only: Callable | None = None  # the value without the gradient's extra solves
    #: for a Gaussian least-squares likelihood: ``residual(eps)`` the whitened residual,
    #: ``residual_jacobian(eps, columns)`` its Jacobian's columns and ``of_rss(rss)`` the
    #: likelihood of a sum of squares, so profiles re-optimize by least squares
    residual: Callable | None = None
    residual_jacobian: Callable | None = None
    of_rss: Callable | None = None
    #: for a likelihood with a variance profiled out inside it (the random-force ECFM's
    #: force scale tau >= 0): ``nuisance(eps)`` its re-estimate at ``eps`` and the
    #: variance term there (half the log-determinant of the data covariance), and
    #: ``simulate(eps, rng)`` the same likelihood of data simulated from the model at
    #: ``eps``, so profiles can flag where it shapes an interval and calibrate their
    #: threshold by simulation
    nuisance: Callable | None = None
    simulate: Callable | None = None

    def __call__(self, eps):
        return self.evaluate(np.asarray(eps, dtype=float))

    def value(self, eps):
        """:math:`\\ell(\\epsilon)` alone (cheaper where ``value_only`` is given)."""
        eps = np.asarray(eps, dtype=float)
        return float(self.value_only(eps) if self.value_only else self.evaluate(eps)[0])


def least_squares_likelihood(rss_and_grad, n_data, n_eps, sigma, what, rss_only=None, *,
                             description=None, **fields):  # fmt: skip
    """``rss_and_grad(eps) -> (||r||^2, d||r||^2/deps)`` to :class:`LogLikelihood`
    (``description`` instead of the default one, ``fields``: more of its fields)."""
    if sigma is not None:
        s2 = float(sigma) ** 2

        def evaluate(eps):
            rss, g = rss_and_grad(eps)
            return 0.5 * rss / s2, 0.5 * g / s2

        return LogLikelihood(
            evaluate, n_eps, n_data, "known sigma",
            description or f"{what}, Gaussian noise sigma={sigma:g}",
            value_only=None if rss_only is None else (lambda eps: 0.5 * rss_only(eps) / s2),
            **fields,
        )  # fmt: skip
    if n_data <= n_eps:
        return (
            f"sigma is unknown and the {n_data} data leave no residual degrees of freedom "
            f"for {n_eps} parameters to estimate it; pass `sigma=` to fit"
        )

    def evaluate(eps):
        rss, g = rss_and_grad(eps)
        if not rss > 0.0:
            # an exact fit: the profiled likelihood is unbounded there
            return -np.inf, np.zeros(n_eps)
        return 0.5 * n_data * np.log(rss), 0.5 * n_data * g / rss

    def value_only(eps):
        rss = rss_only(eps)
        return 0.5 * n_data * np.log(rss) if rss > 0.0 else -np.inf

    return LogLikelihood(
        evaluate, n_eps, n_data, "profiled sigma",
        description or f"{what}, Gaussian noise, sigma profiled out",
        value_only=None if rss_only is None else value_only, **fields,
    )  # fmt: skip


def remember_last_point(residual):
    """``residual(eps) -> (r, J, payload)`` remembering its last point and that point's
    Jacobian (``J`` a callable evaluated once): the residual and then its Jacobian at the
    same point cost one model evaluation, not two."""
    last = {}

    def remembered(eps):
        key = np.asarray(eps, dtype=float).tobytes()
        if last.get("key") != key:
            r, J, payload = residual(eps)
            box = {}

            def jacobian():
                if "J" not in box:
                    box["J"] = J() if callable(J) else J
                return box["J"]

            last.update(key=key, value=(r, jacobian, payload))
        return last["value"]

    # what one Jacobian costs in model evaluations (counted by the drivers), as told
    remembered.jacobian_evaluations = getattr(residual, "jacobian_evaluations", 0)
    return remembered


def gaussian_likelihood(residual, n_data, n_eps, noise, what, residual_columns=None):
    """The :class:`LogLikelihood` of a whitened least-squares residual, or why there is none.

    ``residual(eps) -> (r, J, payload)`` with ``r`` whitened by ``noise``
    (:class:`~ecfm_uq.inverse.problems.noise_model.NoiseModel`) and ``J`` its Jacobian (or a
    callable giving it); ``residual_columns(eps, columns)`` the Jacobian's ``columns`` alone
    (cheaper to difference). Known noise: :math:`\\ell = \\tfrac12\\|r\\|^2`; unknown:
    :math:`\\tfrac n2\\log\\|r\\|^2` (sigma profiled out).
    """

    residual = remember_last_point(residual)
    if residual_columns is None:

        def residual_columns(eps, columns):
            return residual(eps)[1]()[:, columns]

    def jacobian(J):
        return J() if callable(J) else J

    def rss_and_grad(eps):
        r, J, _ = residual(eps)
        return float(r @ r), 2.0 * jacobian(J).T @ r

    def rss_only(eps):
        r = residual(eps)[0]
        return float(r @ r)

    if noise.known:
        desc = f"{what}, Gaussian noise {noise.describe()}"

        def of_rss(rss):
            return 0.5 * rss
    else:
        desc = None  # least_squares_likelihood's

        def of_rss(rss):
            return 0.5 * n_data * np.log(rss) if rss > 0 else -np.inf

    # one construction, its fields all given
    return least_squares_likelihood(
        rss_and_grad, n_data, n_eps, 1.0 if noise.known else None, what, rss_only,
        description=desc, residual=lambda eps: residual(eps)[0],
        residual_jacobian=residual_columns, of_rss=of_rss,
    )  # fmt: skip


def no_likelihood(formulation):
    """Why a fit of ``formulation`` has no likelihood of eps (a string, for messages)."""
    return (
        f"formulation={formulation!r} minimizes constraint forces, not a likelihood of "
        "the data; refit with formulation='standard' (with `sigma`) for likelihood "
        "intervals"
    )
