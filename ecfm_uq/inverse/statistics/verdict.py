"""Whether a fitted model and the data are consistent: one rule for every formulation.

An optimizer's ``success`` only says that it stopped at a stationary point. Every fit also
answers "can this model explain these data?" with a
:class:`~ecfm_uq.inverse.core.result.Verdict` built by :func:`decide`, the one rule: a test
of stated size ``alpha`` (default :data:`DEFAULT_ALPHA` = 0.05 for every formulation) and
``consistent = p_value >= alpha``. The test depends on what the data carry:

* one data set with known noise (``sigma``: a number, one per observation or a
  covariance): the chi-squared test of the unforced model's whitened residual at the
  estimate, :math:`\\|W e\\|^2 \\sim \\chi^2_{n - n_\\epsilon}` (:func:`residual_verdict`);
* the paper's noisy ECFM: its z and chi-squared moment bounds (Eq. ecfm_noise), combined
  by Bonferroni (:func:`moments_bounds_verdict`);
* replicated data: z-tests of the sensor means against the model's moments, Bonferroni
  over the sensors (:func:`~ecfm_uq.inverse.problems.moments.moment_verdict`);
* the random-force ECFM: the restricted likelihood-ratio test of :math:`\tau = 0`;
* the exact-match ECFM on noise-free data (paper Eq. ecfm): no test has a size; the
  forces must change the observations by at most ``rtol`` of the data (they vanish at a
  consistent fit and stay large on data the model cannot explain), labelled as such;
* a least-squares fit with neither ``sigma`` nor replicates: **no test**. A residual has
  no scale to be judged against, so ``consistent`` is ``None`` and the message says what
  to give (``sigma``, replicates).

An estimate at a bound or a coefficient at an extreme value is an identifiability
finding, not a failed test: it is reported in ``Verdict.identifiability`` (which
parameters, which side) and in the message, and never changes ``consistent``.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..._validation import as_finite_array, as_operator, check_fraction, check_positive
from ...errors import ModelEvaluationError
from ...system import solve_steady
from ..core.convergence import at_bound
from ..core.result import Verdict

#: default for ``rtol``: the forces may change the observations by 0.1 % of the data
FORCE_TO_DATA_RTOL = 1e-3
#: default for ``extreme_decades``: a coefficient outside [1e-8, 1e8] is extreme
EXTREME_DECADES = 8.0
#: the size of every consistency test unless the caller chooses another
DEFAULT_ALPHA = 0.05
#: the name of the exact-match ECFM's rule (noise-free data, no test of stated size)
FORCE_RULE = "force-to-data (exact-match ECFM, noise-free)"


def check_alpha(alpha):
    """``alpha`` as a float in (0, 1): TypeError for a non-number, ValueError outside."""
    return check_fraction("alpha", alpha, " (the size of the consistency test, e.g. 0.05)")


def decide(test, p_value, alpha, parts, *, statistic=None, explained=None, at_bound=(),
           extreme=(), details=None):  # fmt: skip
    """The one rule: a :class:`~ecfm_uq.inverse.core.result.Verdict` from a test's p-value and the fit's state.

    Parameters
    ----------
    test : str
        Name of the test.
    p_value : float or None
        ``None`` for a rule without a size (then ``explained`` decides) or no test.
    alpha : float or None
        The test's size.
    parts : list of str
        Sentences describing the test's outcome (joined into the message).
    statistic : float, optional
    explained : bool or None, optional
        Whether the data are explained, for a rule without a p-value; ``None`` (and no
        ``p_value``): no test, ``consistent`` is ``None``.
    at_bound : sequence of int or of (int, str)
        Parameters at a bound (with the side, ``"lower"``/``"upper"``).
    extreme : sequence of (name, value)
        Coefficients at an extreme value.
    details : dict, optional

    Returns
    -------
    Verdict
    """
    if p_value is not None:
        explained = bool(p_value >= alpha)
    at_bound = [b if isinstance(b, tuple) else (int(b), "") for b in at_bound]
    findings = []
    if at_bound:
        where = ", ".join(f"{i} ({side})" if side else str(i) for i, side in at_bound)
        findings.append(
            f"parameters [{where}] at a bound: the data do not keep them inside (a ridge or "
            "a flat likelihood); see profile_likelihood(result).regions"
        )
    if extreme:
        name, c = extreme[0]
        findings.append(f"coefficient of term {name!r} is extreme ({c:.3g})")
    parts = list(parts)
    consistent = None if explained is None else bool(explained)
    word = {
        True: "model and data are consistent",
        False: "NOT consistent",
        None: "no consistency test",
    }[consistent]
    details = dict(details or {})
    details.setdefault("at_bound", [i for i, _ in at_bound])
    details.setdefault("extreme", list(extreme))
    message = f"{word}: " + "; ".join(parts)
    if findings:
        message += "; identifiability: " + "; ".join(findings)
    return Verdict(
        consistent=consistent,
        p_value=None if p_value is None else float(p_value),
        alpha=None if p_value is None else float(alpha),
        test=test,
        statistic=None if statistic is None else float(statistic),
        message=message,
        details=details,
        identifiability="; ".join(findings),
    )


def no_test(reason=None, *, at_bound=(), extreme=(), details=None):
    """The verdict of a fit whose data carry no noise model: ``consistent=None``."""
    reason = reason or (
        "without a noise level a residual has no scale to be judged against; pass "
        "`sigma` (a number, one per observation or a covariance) or fit replicated data "
        "for a chi-squared test"
    )
    return decide("none", None, None, [reason], explained=None, at_bound=at_bound,
                  extreme=extreme, details=details)  # fmt: skip


def moments_bounds_verdict(test, sigma, alpha=DEFAULT_ALPHA, at_bound=(), sigma_label=None):
    """The paper's noise test (Eq. ecfm_noise) as a :class:`~ecfm_uq.inverse.core.result.Verdict`.

    The two-sided z test of the discrepancy's sample mean and the chi-squared test of
    its sample variance, each at the paper's level, combined by Bonferroni into one
    p-value :math:`\\min(1, 2\\min(p_{mean}, p_{var}))`.

    Parameters
    ----------
    test : ConsistencyTest
        From :func:`~ecfm_uq.inverse.formulations.noise_bounds.consistency_test`.
    sigma : float
    alpha : float
    at_bound : sequence of int
    sigma_label : str, optional
        How the message names the noise (``"sigma=1 (whitened: ...)"`` for a fit of
        whitened data, :class:`~ecfm_uq.inverse.core.settings.FitSettings`); default
        ``"sigma = <sigma>"``.
    """
    from scipy import stats

    C = test.bounds["n_sensors"]
    z = test.mean / (sigma / np.sqrt(C))
    p_mean = 2.0 * stats.norm.sf(abs(z))
    q = test.var * (C - 1) / sigma**2
    p_var = 2.0 * min(stats.chi2.sf(q, C - 1), stats.chi2.cdf(q, C - 1))
    p = min(1.0, 2.0 * min(p_mean, p_var))
    parts = [
        f"discrepancy mean {test.mean:.3g} (p = {p_mean:.2g}), variance {test.var:.3g} "
        f"(p = {p_var:.2g}) against {sigma_label or f'sigma = {sigma:g}'}, Bonferroni p = {p:.3g} "
        f"{'>=' if p >= alpha else '<'} alpha = {alpha:g}"
    ]
    return decide(
        "moments z and chi2 (Bonferroni)", p, alpha, parts, statistic=q, at_bound=at_bound,
        details={"mean": test.mean, "var": test.var, "p_mean": p_mean, "p_var": p_var},
    )  # fmt: skip


def consistency_verdict(
    system,
    M_obs,
    v,
    eps,
    lam=None,
    bounds=None,
    *,
    sigma=None,
    alpha=DEFAULT_ALPHA,
    n_fitted=0,
    rtol=FORCE_TO_DATA_RTOL,
    extreme_decades=EXTREME_DECADES,
    solve_options=None,
    solution=None,
):
    """Say whether model and data agree at fitted parameters ``eps`` (one data set).

    Parameters
    ----------
    system : GalerkinSystem
    M_obs : (C, N) array_like or scipy.sparse matrix
        Measurement operator :math:`\\mathcal M`.
    v : (C,) array_like
        Observations.
    eps : (n_eps,) array_like
        Fitted parameters.
    lam : (n_forces,) array_like, optional
        Fitted constraint forces :math:`\\lambda` (ECFM); only used to locate the
        largest force.
    bounds : sequence of (lo, hi), optional
        The optimizer's bounds (``None`` entries for open sides).
    sigma : float, optional
        Noise standard deviation of ``v``. Given, the verdict is the chi-squared test
        :math:`\\chi^2 = \\|e\\|^2/\\sigma^2` with ``C - n_fitted`` degrees of freedom at
        size ``alpha``; otherwise (noise-free data) it is ``force_to_data <= rtol``.
    alpha : float
        Size of the test (default 0.05, as for every formulation).
    n_fitted : int
        Parameters fitted to ``v`` (a fit passes ``n_eps``; 0 for given parameters).
    rtol : float
        Threshold on ``force_to_data`` for noise-free data (default 1e-3).
    extreme_decades : float
        A coefficient :math:`c(\\epsilon)` with :math:`|\\log_{10}|c|| >` this is reported
        as extreme (default 8: outside [1e-8, 1e8]).
    solve_options : dict, optional
        Passed to :func:`~ecfm_uq.system.solve_steady`.
    solution : SteadySolution, optional
        The unforced solve at ``eps`` if the caller has it (not solved again).

    Returns
    -------
    Verdict
        ``details`` (``verdict.details["force_to_data"]``, ...): ``force_to_data``
        (:math:`\\|e\\|/\\|v\\|` with :math:`e = v - \\mathcal M\\,\\mathbb E[\\theta(\\epsilon,
        \\lambda=0)]`, what the forces must add to the unforced model's observations;
        ``inf`` when the model cannot be solved at ``eps``), ``peak_sensor_index`` (where
        :math:`|e|` peaks), ``peak_force_index`` (where :math:`|\\lambda|` peaks),
        ``chi2``, ``chi2_limit``, ``dof`` (with ``sigma``), ``at_bound`` (parameters within
        1e-8 of a bound, relative to its width), ``extreme`` (``(term, value)`` pairs).
    """
    M_obs = as_operator("M_obs", M_obs)
    v = as_finite_array("v", v, shape=(M_obs.shape[0],))
    eps = system.check_eps(eps)
    rtol = check_positive("rtol", rtol)
    alpha = check_alpha(alpha)
    extreme_decades = check_positive("extreme_decades", extreme_decades)
    lam = None if lam is None else as_finite_array("lam", lam).ravel()
    bounds = check_bounds(bounds, system.n_eps)
    out = {"force_to_data": np.inf, "peak_sensor_index": None, "peak_force_index": None}
    if lam is not None and lam.size:
        out["peak_force_index"] = int(np.argmax(np.abs(lam)))
    sol = solve_steady(system, eps, **dict(solve_options or {})) if solution is None else solution
    hits, extreme = at_bound(eps, bounds), extreme_coefficients(system, eps, extreme_decades)
    forces = lam is not None and lam.size > 0
    if not sol.success:
        parts = [f"the unforced model cannot be solved at eps={eps.tolist()}: {sol.message}"]
        test = "chi2" if sigma is not None else FORCE_RULE
        return decide(
            test, None if sigma is None else 0.0, alpha, parts, explained=False,
            at_bound=hits, extreme=extreme, details=out,
        )  # fmt: skip
    e = v - M_obs @ system.mean(sol.Theta)
    return residual_verdict(
        e, v, sigma, alpha, n_fitted, rtol=rtol, at_bound=hits, extreme=extreme,
        details=out, forces=forces,
    )  # fmt: skip


def residual_verdict(e, v, sigma=None, alpha=DEFAULT_ALPHA, n_fitted=0, *, rtol=FORCE_TO_DATA_RTOL,
                     at_bound=(), extreme=(), details=None, forces=False):  # fmt: skip
    """The verdict from the unforced model's residual ``e = v - M theta(eps, lam=0)``.

    With ``sigma``: the chi-squared test :math:`\\|e\\|^2/\\sigma^2 \\sim
    \\chi^2_{n - n_{fitted}}` at size ``alpha``. Without: for the exact-match ECFM
    (``forces``) the noise-free rule ``force_to_data = ||e|| / ||v|| <= rtol``; for a
    least-squares fit no test (:func:`no_test`).

    Parameters
    ----------
    e, v : array_like
        Residual and data, any matching shape (a time series is flattened).
    sigma : float, optional
    alpha : float
    n_fitted : int
        Parameters fitted to the data (degrees of freedom lost).
    rtol : float
    at_bound, extreme, details
        As in :func:`decide`; ``details`` gains ``force_to_data``, ``peak_sensor_index``
        (flat index of the largest ``|e|``) and ``chi2``, ``chi2_limit``, ``dof``.

    Returns
    -------
    Verdict
    """
    e = np.ravel(np.asarray(e, dtype=float))
    v = np.ravel(np.asarray(v, dtype=float))
    out = dict(details or {})
    # np.linalg.norm of a real vector is sqrt(x.x): the same bits without its wrapper
    out["force_to_data"] = float(math.sqrt(e.dot(e)) / max(math.sqrt(v.dot(v)), 1e-300))
    out["peak_sensor_index"] = int(np.abs(e).argmax())  # np.argmax without its wrapper
    force = out.get("peak_force_index")
    where = "" if force is None else f"; largest force {force}"
    if sigma is None:
        if not forces:
            return no_test(at_bound=at_bound, extreme=extreme, details=out)
        explained = out["force_to_data"] <= rtol
        parts = [
            f"the forces change the observations by {out['force_to_data']:.2e} of the "
            f"data ({'<=' if explained else '>'} rtol={rtol:g}), most at sensor "
            f"{out['peak_sensor_index']}{where}"
        ]
        return decide(
            FORCE_RULE, None, alpha, parts, explained=explained,
            at_bound=at_bound, extreme=extreme, details=out,
        )  # fmt: skip
    from scipy.stats import chi2

    sigma = check_positive("sigma", sigma)
    r = e / sigma  # not (e @ e) / sigma**2: sigma**2 may overflow
    dof = max(e.size - int(n_fitted), 1)
    statistic = float(r @ r)
    p_value = float(chi2.sf(statistic, df=dof))
    out.update(chi2=statistic, chi2_limit=float(chi2.ppf(1 - alpha, df=dof)), dof=dof)
    parts = [
        f"chi2 = {statistic:.3g} on {dof} degrees of freedom, p = {p_value:.3g} "
        f"{'>=' if p_value >= alpha else '<'} alpha = {alpha:g}{where}"
    ]
    return decide(
        "chi2", p_value, alpha, parts, statistic=statistic, at_bound=at_bound,
        extreme=extreme, details=out,
    )  # fmt: skip


def check_bounds(bounds, n_eps, eps0=None):
    """Validate optimizer ``bounds``: ``n_eps`` pairs ``(lo, hi)`` of numbers or None,
    ``lo < hi``, and (given ``eps0``, a start of ``n_eps`` numbers) containing the start.

    Returns
    -------
    list of tuple or None
    """
    if bounds is None:
        return None
    try:
        pairs = [tuple(b) for b in bounds]
        ok = len(pairs) == n_eps and all(len(b) == 2 for b in pairs)
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(
            f"`bounds` must be {n_eps} pairs (lo, hi), one per parameter "
            f"(None for an open side), got {bounds!r:.60}"
        )
    for m, (lo, hi) in enumerate(pairs):
        for side in (lo, hi):
            if side is not None and (
                isinstance(side, bool) or not isinstance(side, numbers.Real) or np.isnan(side)
            ):
                raise ValueError(f"`bounds[{m}]` must hold numbers or None, got {(lo, hi)}")
        if lo is not None and hi is not None and lo > hi:
            raise ValueError(f"`bounds[{m}]` has lo > hi: {(lo, hi)}; swap them")
        if lo is not None and hi is not None and lo == hi:
            raise ValueError(
                f"`bounds[{m}]` has lo == hi == {lo}: a parameter fixed by its bounds is not "
                "fitted; fix it inside the model and drop it from eps0, or widen the bounds"
            )
    start = _start(eps0, n_eps)
    for m, (lo, hi) in enumerate(pairs if start is not None else ()):
        if (lo is not None and start[m] < lo) or (hi is not None and start[m] > hi):
            raise ValueError(
                f"`eps0[{m}]` = {start[m]:g} lies outside `bounds[{m}]` = {(lo, hi)}: start "
                "inside the bounds (move eps0 or widen the bounds)"
            )
    return pairs


def _start(eps0, n_eps):
    """``eps0`` as a finite (n_eps,) array, or None when it is not one (its own checks,
    downstream, name that)."""
    if eps0 is None:
        return None
    try:
        start = np.asarray(eps0, dtype=float).ravel()
    except (TypeError, ValueError):
        return None
    return start if start.size == n_eps and np.all(np.isfinite(start)) else None


def extreme_coefficients(system, eps, decades):
    """The terms whose coefficient at ``eps`` lies more than ``decades`` decades from 1, as
    ``(name, value)`` pairs (an identifiability finding: a rate gone to zero or infinity)."""
    found = []
    for term in system.terms:
        coef = getattr(term, "coef", None)
        if coef is None or not getattr(coef, "indices", None):
            continue  # constant or unknown dependence on eps
        try:
            c = float(coef.value(eps))
        except ModelEvaluationError:  # overflow: as extreme as it gets
            found.append((term.name, np.inf))
            continue
        if c != 0.0 and abs(np.log10(abs(c))) > decades:
            found.append((term.name, c))
    return found


def model_verdict(r, v, noise, n_fitted, bounds, eps, *, alpha=DEFAULT_ALPHA, failed=None):
    """The verdict of a least-squares fit of whitened residual ``r`` to whitened data ``v``:
    the chi-squared test with known noise, no test without (:func:`no_test`)."""
    hits = at_bound(eps, bounds)
    if failed is not None:
        return decide("chi2" if noise.known else "none", 0.0 if noise.known else None, alpha,
                      [f"the model cannot be evaluated at the estimate: {failed}"],
                      explained=False if noise.known else None, at_bound=hits)  # fmt: skip
    return residual_verdict(r, v, 1.0 if noise.known else None, alpha, n_fitted, at_bound=hits)
