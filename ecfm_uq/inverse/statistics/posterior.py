"""Posterior sampling of the standard Gaussian likelihood with emcee (issue 13).

For any system, data :math:`v` with Gaussian sensor noise of known :math:`\\sigma` and a
prior :math:`p(\\epsilon)`,

.. math::

    \\log p(\\epsilon \\mid v) = -\\frac{1}{2\\sigma^2}
        \\|\\mathcal M\\,\\mathbb E[\\theta(\\epsilon)] - v\\|^2 + \\log p(\\epsilon) + c,

sampled by the affine-invariant ensemble sampler of emcee (optional extra ``bayes``).
The chain is declared converged only when it is at least 50 integrated autocorrelation
times long (emcee's own rule of thumb); the effective sample size is
``n_walkers * n_kept / tau``. On a (nearly) linear model the posterior is the Laplace
approximation :math:`N(\\hat\\epsilon, \\sigma^2 (J^TJ)^{-1})` of
:func:`~ecfm_uq.inverse.fit` of a :class:`~ecfm_uq.inverse.SteadyProblem` with ``sigma``.

A fit whose :math:`\\sigma` was estimated (its likelihood has sigma profiled out) is
sampled with :math:`\\sigma` as an unknown too, under the Jeffreys prior
:math:`p(\\sigma) \\propto 1/\\sigma` (flat in :math:`\\log\\sigma`), independent of
:math:`p(\\epsilon)`. Integrating :math:`\\sigma` out,

.. math::

    p(\\epsilon \\mid v) \\propto p(\\epsilon)\\int_0^\\infty \\sigma^{-n}
        e^{-\\|r(\\epsilon)\\|^2/2\\sigma^2}\\,\\frac{d\\sigma}{\\sigma}
        \\propto p(\\epsilon)\\,\\|r(\\epsilon)\\|^{-n},

which is exactly the profiled likelihood the fit carries, so the chain runs on it; then
each sample's :math:`\\sigma` is drawn from its conditional,
:math:`\\|r(\\epsilon)\\|^2/\\sigma^2 \\sim \\chi^2_n` (``PosteriorResult.sigma``). For a
linear model with a flat prior the marginal posterior of :math:`\\epsilon` is then the
multivariate t with :math:`n - p` degrees of freedom, location :math:`\\hat\\epsilon` and
scale :math:`s^2(X^TX)^{-1}`, and :math:`\\sigma^2 \\sim \\|r(\\hat\\epsilon)\\|^2 /
\\chi^2_{n-p}`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..._validation import (
    as_finite_array,
    as_operator,
    check_int,
    check_positive,
    rng_from_seed,
)
from ...errors import ConvergenceError
from ...system import solve_steady
from ..core.result import InverseResult
from ..core.status import FitStatus

__all__ = ["PosteriorResult", "sample_posterior", "uniform_box_prior"]

#: a chain shorter than this many autocorrelation times is not converged
MIN_TAU_MULTIPLES = 50


@dataclass
class PosteriorResult:
    """Samples of the posterior and the sampler's diagnostics.

    Attributes
    ----------
    chain : (n_steps, n_walkers, n_eps) ndarray
        Every step of every walker.
    samples : (n_samples, n_eps) ndarray
        The chain after the burn-in ``burn`` steps, walkers pooled.
    mean : (n_eps,) ndarray
    cov : (n_eps, n_eps) ndarray
    tau : (n_eps,) ndarray
        Integrated autocorrelation time per parameter (steps).
    ess : (n_eps,) ndarray
        Effective sample size ``n_walkers * (n_steps - burn) / tau``.
    burn : int
        Steps discarded (twice the largest tau).
    acceptance : float
        Mean acceptance fraction.
    success : bool
        The chain converged: ``n_steps >= 50 * max(tau)`` (``status`` CONVERGED; else
        MAX_ITERATIONS, with the chain length needed in ``message``).
    status : FitStatus
    message : str
    nfev : int
        Log-posterior evaluations (model solves inside the prior's support).
    sigma : (n_samples,) ndarray or None
        The noise standard deviation of each sample, when sigma was estimated by the fit
        (sampled under the Jeffreys prior, see the module docstring); ``None`` when it was
        known.
    sigma_prior : str
        ``"jeffreys"`` when ``sigma`` is sampled, else ``""``.
    """

    chain: np.ndarray
    samples: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    tau: np.ndarray
    ess: np.ndarray
    burn: int
    acceptance: float
    success: bool
    message: str
    status: FitStatus = FitStatus.CONVERGED
    nfev: int = 0
    sigma: np.ndarray | None = None
    sigma_prior: str = ""

    @property
    def converged(self):
        """v0.2 name of ``success``."""
        return self.success


def uniform_box_prior(bounds):
    """Log density of the uniform prior on the box ``bounds`` (0 inside, -inf outside).

    Parameters
    ----------
    bounds : sequence of (lo, hi)
        Finite, ``lo < hi``, one pair per parameter.
    """
    try:
        b = np.array(bounds, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"`bounds` must be (lo, hi) pairs of numbers, got {bounds!r}") from e
    if b.ndim != 2 or b.shape[1] != 2 or not np.all(np.isfinite(b)) or np.any(b[:, 0] >= b[:, 1]):
        raise ValueError(
            f"`bounds` of a uniform prior must be finite (lo, hi) pairs with lo < hi, got "
            f"{bounds!r}"
        )
    lo, hi = b[:, 0], b[:, 1]

    def log_prior(eps):
        return 0.0 if np.all((lo <= eps) & (eps <= hi)) else -np.inf

    log_prior.bounds = b
    return log_prior


def sample_posterior(
    system,
    M_obs=None,
    v=None,
    sigma=None,
    eps0=None,
    *,
    prior=None,
    bounds=None,
    n_walkers=None,
    n_steps=2000,
    seed=0,
    init_scale=1e-3,
    solve_options=None,
):
    """Sample :math:`p(\\epsilon\\mid v)` of the standard Gaussian likelihood with emcee.

    ``sample_posterior(result, prior=..., ...)`` samples the likelihood a fit carries
    (``result.likelihood`` of :func:`~ecfm_uq.inverse.fit`): steady and dynamic least
    squares with ``sigma`` known, the least squares of a ModelProblem or a SteadyProblem
    with sigma estimated (sigma then sampled too, under the Jeffreys prior
    :math:`p(\\sigma) \\propto 1/\\sigma`: ``PosteriorResult.sigma``), and the random-force
    ECFM (its likelihood with the estimated discrepancy covariance held fixed), starting
    at the estimate. Likelihoods that are not a density of the data given eps are
    refused: the replicated pseudo-likelihood, the force objectives.

    Parameters
    ----------
    system : InverseResult or GalerkinSystem
        The fit to sample from (the one entry: the first argument is a result). A
        :class:`~ecfm_uq.system.GalerkinSystem` with ``M_obs``, ``v``, ``sigma`` and
        ``eps0`` is deprecated (it warns): fit a
        :class:`~ecfm_uq.inverse.SteadyProblem` and pass the result.
    M_obs : (C, N) array_like or scipy.sparse matrix
    v : (C,) array_like
    sigma : float
        Known sensor noise standard deviation.
    eps0 : (n_eps,) array_like
        Start: the walkers begin in a small ball around it (e.g. the least-squares fit).
    prior : callable ``eps -> log p(eps)``, optional
        Log prior density (up to a constant); ``-inf`` outside its support.
    bounds : sequence of (lo, hi), optional
        Without ``prior``: the uniform box prior (:func:`uniform_box_prior`); one of the
        two is required.
    n_walkers : int, optional
        Default ``max(4 n_eps, 8)`` (even).
    n_steps : int
    seed : int
    init_scale : float
        Radius of the starting ball, relative to ``max(|eps0|, 1)``.
    solve_options : dict, optional
        Passed to :func:`~ecfm_uq.system.solve_steady`; a failed solve counts as zero
        likelihood.

    Returns
    -------
    PosteriorResult

    Raises
    ------
    ImportError
        Without emcee (``pip install ecfm-uq[bayes]``).
    ValueError
        For ``sigma <= 0``, a prior with no mass at ``eps0``, or bad sizes.
    """
    try:
        import emcee  # optional: the bayes extra, only when sampling is asked for
    except ImportError as e:  # pragma: no cover - emcee is in the test extra
        raise ImportError("sample_posterior needs emcee: pip install 'ecfm-uq[bayes]'") from e

    n_data = None  # sigma sampled (Jeffreys) for a profiled likelihood of this many data
    if isinstance(system, InverseResult):
        log_like, eps0, n_data = _result_likelihood(system, M_obs, v, sigma, eps0)
    else:
        warnings.warn(
            "sample_posterior(system, M_obs, v, sigma, eps0) is deprecated: sample from a "
            "fit, sample_posterior(fit(SteadyProblem(system, M_obs, v), eps0, sigma=sigma), "
            "bounds=...) (the one entry: the likelihood the result carries, started at its "
            "estimate)",
            DeprecationWarning,
            stacklevel=2,
        )
        sigma = check_positive("sigma", sigma)
        M_obs = as_operator("M_obs", M_obs, shape=(None, system.N))
        v = as_finite_array("v", v, shape=(M_obs.shape[0],))
        eps0 = system.check_eps(eps0)
        opts = dict(solve_options or {})

        def log_like(eps):
            try:
                sol = solve_steady(system, eps, strict=True, **opts)
            except (ConvergenceError, ValueError):
                return -np.inf
            r = (M_obs @ system.mean(sol.Theta) - v) / sigma
            return -0.5 * float(r @ r)

    n = eps0.size
    if prior is None:
        if bounds is None:
            raise ValueError("give a `prior` (log density) or `bounds` for the uniform box prior")
        prior = uniform_box_prior(bounds)
    elif not callable(prior):
        raise TypeError(f"`prior` must be callable eps -> log p(eps), got {prior!r}")
    lp0 = float(prior(eps0))
    if not np.isfinite(lp0):
        raise ValueError(
            f"the `prior` has no mass at the start eps0={eps0.tolist()} (log p = {lp0}); "
            "start inside its support or widen the prior"
        )
    n_walkers = max(4 * n, 8) if n_walkers is None else check_int("n_walkers", n_walkers)
    if n_walkers < 2 * n or n_walkers % 2:
        raise ValueError(f"`n_walkers` must be even and >= 2 n_eps = {2 * n}, got {n_walkers}")
    n_steps = check_int("n_steps", n_steps, minimum=10)
    init_scale = check_positive("init_scale", init_scale)
    nfev = [0]

    def log_post(eps):
        lp = prior(eps)
        if not np.isfinite(lp):
            return -np.inf, np.nan
        nfev[0] += 1
        ll = log_like(eps)
        return lp + ll, ll  # the log-likelihood as a blob: the sum of squares of sigma

    rng = rng_from_seed("seed", seed)
    start = []
    while len(start) < n_walkers:
        p = eps0 + init_scale * np.maximum(np.abs(eps0), 1.0) * rng.standard_normal(n)
        if np.isfinite(prior(p)):
            start.append(p)
    sampler = emcee.EnsembleSampler(n_walkers, n, log_post)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    sampler.run_mcmc(np.array(start), n_steps, progress=False)
    chain = sampler.get_chain()
    tau = np.asarray(sampler.get_autocorr_time(tol=0), dtype=float)
    burn = int(min(np.ceil(2 * tau.max()), n_steps // 2))
    samples = chain[burn:].reshape(-1, n)
    sigma_draws = None
    if n_data is not None:
        # -log-likelihood = (n/2) log ||r||^2, so ||r||^2 = exp(-2 ll / n); then
        # ||r||^2 / sigma^2 ~ chi2_n given eps (Jeffreys prior)
        ll = np.asarray(sampler.get_blobs(), dtype=float)[burn:].reshape(-1)
        rss = np.exp(-2.0 * ll / n_data)
        sigma_draws = np.sqrt(rss / rng.chisquare(n_data, size=rss.size))
    converged = bool(n_steps >= MIN_TAU_MULTIPLES * tau.max())
    msg = (
        f"chain of {n_steps} steps = {n_steps / tau.max():.1f} autocorrelation times "
        f"(tau max {tau.max():.1f})"
    )
    msg += (
        ": converged"
        if converged
        else f" < {MIN_TAU_MULTIPLES}: NOT converged; run at least "
        f"{int(np.ceil(MIN_TAU_MULTIPLES * tau.max()))} steps"
    )
    return PosteriorResult(
        chain=chain,
        samples=samples,
        mean=samples.mean(axis=0),
        cov=np.atleast_2d(np.cov(samples, rowvar=False)),
        tau=tau,
        ess=n_walkers * (n_steps - burn) / tau,
        burn=burn,
        acceptance=float(np.mean(sampler.acceptance_fraction)),
        success=converged,
        message=msg,
        status=FitStatus.CONVERGED if converged else FitStatus.MAX_ITERATIONS,
        nfev=nfev[0],
        sigma=sigma_draws,
        sigma_prior="" if sigma_draws is None else "jeffreys",
    )


def _result_likelihood(result, *unused):
    """``log p(v | eps)`` (up to a constant) of a fit, its estimate as the start, and the
    number of data when sigma is profiled out (sampled too), else ``None``."""
    if any(u is not None for u in unused):
        raise TypeError(
            "sample_posterior(result, ...) takes the data and sigma from the fit; pass only "
            "keywords (prior, bounds, n_walkers, n_steps, seed, init_scale)"
        )
    like = getattr(result, "likelihood", None)
    if like is None or isinstance(like, str):
        raise ValueError(f"`result` has no likelihood to sample: {like or 'not made by fit'}")
    profiled = like.noise == "profiled sigma"
    if profiled and like.residual is None:
        raise ValueError(
            f"`result`'s likelihood ({like.description}) profiles sigma out, which is not "
            "a density of the data given eps; sigma is sampled with eps (Jeffreys prior) "
            "only for fits whose likelihood carries its residual (ModelProblem, "
            "SteadyProblem); refit with `sigma` known"
        )
    if like.noise not in ("known sigma", "random forces") and not profiled:
        raise ValueError(
            f"`result`'s likelihood ({like.description}) is not a density of the data given "
            "eps; refit with `sigma` known (formulation 'standard' or 'ecfm')"
        )
    failures = (ConvergenceError, ValueError, np.linalg.LinAlgError)

    def log_like(eps):
        try:
            return -like.value(eps)
        except failures:
            return -np.inf

    return log_like, np.asarray(result.eps, dtype=float), like.n_data if profiled else None
