"""Whether a fitted model and the data are consistent (issue 15).

An optimizer's ``success`` only says that it stopped at a stationary point. For ECFM
(paper Eq. ecfm) the constraint forces :math:`\\Gamma\\lambda` carry whatever the model
cannot explain: at a consistent fit they vanish, on data the model cannot explain they
stay large. :func:`consistency_verdict` measures how much the forces had to do, in the
units of the data, and whether the parameters ran to a bound or to an extreme value.
"""

from __future__ import annotations

import numbers

import numpy as np

from .._validation import as_finite_array, as_operator, check_positive
from ..errors import ModelEvaluationError

#: default for ``rtol``: the forces may change the observations by 0.1 % of the data
FORCE_TO_DATA_RTOL = 1e-3
#: default for ``extreme_decades``: a coefficient outside [1e-8, 1e8] is extreme
EXTREME_DECADES = 8.0


def consistency_verdict(
    system,
    M_obs,
    v,
    eps,
    lam=None,
    bounds=None,
    *,
    sigma=None,
    rtol=FORCE_TO_DATA_RTOL,
    extreme_decades=EXTREME_DECADES,
    solve_options=None,
    solution=None,
):
    """Say whether model and data agree at fitted parameters ``eps``.

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
        :math:`\\chi^2 = \\|e\\|^2/\\sigma^2` at the 99 % quantile of :math:`\\chi^2_C`;
        otherwise (noise-free data) it is ``force_to_data <= rtol``.
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
    dict
        ``force_to_data``
            :math:`\\|e\\|/\\|v\\|` with :math:`e = v - \\mathcal M\\,\\mathbb E[\\theta(\\epsilon,
            \\lambda=0)]`: what the forces must add to the unforced model's observations,
            relative to the data (``inf`` when the model cannot be solved at ``eps``).
        ``peak_sensor_index``
            Sensor where :math:`|e|` peaks (``None`` if unsolved).
        ``peak_force_index``
            Force where :math:`|\\lambda|` peaks (``None`` without ``lam``).
        ``chi2``, ``chi2_limit``
            Only with ``sigma``.
        ``at_bound``
            Indices of parameters within 1e-8 (relative to the bound's width, or absolute
            for one-sided bounds) of a bound.
        ``extreme``
            ``(term name, coefficient value)`` pairs of coefficients outside the
            ``extreme_decades`` range.
        ``consistent``
            True when the data are explained (see ``sigma``/``rtol``) and no parameter is
            at a bound or extreme.
        ``message``
            One sentence saying the above.
    """
    from ..system import solve_steady

    M_obs = as_operator("M_obs", M_obs)
    v = as_finite_array("v", v, shape=(M_obs.shape[0],))
    eps = system.check_eps(eps)
    rtol = check_positive("rtol", rtol)
    extreme_decades = check_positive("extreme_decades", extreme_decades)
    lam = None if lam is None else as_finite_array("lam", lam).ravel()
    bounds = check_bounds(bounds, system.n_eps)
    out = {"force_to_data": np.inf, "peak_sensor_index": None, "peak_force_index": None}
    if lam is not None and lam.size:
        out["peak_force_index"] = int(np.argmax(np.abs(lam)))
    parts = []
    sol = solve_steady(system, eps, **dict(solve_options or {})) if solution is None else solution
    if sol.success:
        e = v - M_obs @ system.mean(sol.Theta)
        out["force_to_data"] = float(np.linalg.norm(e) / max(np.linalg.norm(v), 1e-300))
        out["peak_sensor_index"] = int(np.argmax(np.abs(e)))
        if sigma is not None:
            from scipy.stats import chi2

            sigma = check_positive("sigma", sigma)
            r = e / sigma  # not (e @ e) / sigma**2: sigma**2 may overflow
            out["chi2"] = float(r @ r)
            out["chi2_limit"] = float(chi2.ppf(0.99, df=v.size))
            explained = out["chi2"] <= out["chi2_limit"]
            parts.append(
                f"chi2 = {out['chi2']:.3g} {'<=' if explained else '>'} "
                f"{out['chi2_limit']:.3g} (99 % quantile, {v.size} sensors)"
            )
        else:
            explained = out["force_to_data"] <= rtol
            parts.append(
                f"the forces change the observations by {out['force_to_data']:.2e} of the "
                f"data ({'<=' if explained else '>'} rtol={rtol:g}), most at sensor "
                f"{out['peak_sensor_index']}"
            )
        if out["peak_force_index"] is not None:
            parts[-1] += f"; largest force {out['peak_force_index']}"
    else:
        explained = False
        parts.append(f"the unforced model cannot be solved at eps={eps.tolist()}: {sol.message}")
    out["at_bound"] = _at_bound(eps, bounds)
    if out["at_bound"]:
        parts.append(f"parameters {out['at_bound']} are at a bound")
    out["extreme"] = _extreme(system, eps, extreme_decades)
    if out["extreme"]:
        name, c = out["extreme"][0]
        parts.append(f"coefficient of term {name!r} is extreme ({c:.3g}) at eps={eps.tolist()}")
    out["consistent"] = bool(explained and not out["at_bound"] and not out["extreme"])
    verdict = "model and data are consistent" if out["consistent"] else "NOT consistent"
    out["message"] = f"{verdict}: " + "; ".join(parts)
    return out


def check_bounds(bounds, n_eps):
    """Validate optimizer ``bounds``: ``n_eps`` pairs ``(lo, hi)`` of numbers or None.

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
    return pairs


def _at_bound(eps, bounds):
    if bounds is None:
        return []
    hits = []
    for m, (x, b) in enumerate(zip(eps, bounds, strict=False)):
        lo, hi = (None, None) if b is None else b
        width = (hi - lo) if lo is not None and hi is not None else 1.0
        tol = 1e-8 * max(abs(width), 1e-300)
        if (lo is not None and x <= lo + tol) or (hi is not None and x >= hi - tol):
            hits.append(m)
    return hits


def _extreme(system, eps, decades):
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
