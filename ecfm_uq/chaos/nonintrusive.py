"""Non-intrusive polynomial chaos: a PCE of a black-box model from its evaluations.

One entry point, :func:`fit_pce`, dispatches on ``method`` to

* ``"quadrature"``: pseudo-spectral projection on a tensor Gauss rule of the germs
  (Gauss-Legendre for uniform inputs, Gauss-Hermite for normal ones, ...),
  :math:`c_k = \\sum_q w_q\\, y(x_q)\\,\\Psi_k(\\omega_q) / \\mathbb E[\\Psi_k^2]`;
* ``"smolyak"``: the Smolyak combination of tensor pseudo-spectral projections
  (Conrad & Marzouk 2013), on non-nested Gauss-Legendre rules (``rule="gauss"``, linear
  growth: exact for total degree ``order``) or nested Clenshaw-Curtis rules
  (``rule="clenshaw-curtis"``, doubling growth, shared nodes evaluated once);
* ``"lstsq"``: ordinary least squares on a total-degree basis at given or generated
  samples (Latin hypercube, scrambled Sobol', Halton or plain random from
  ``scipy.stats.qmc``), with the closed-form leave-one-out error;
* ``"lars"``: sparse regression by least-angle regression with a hybrid OLS refit and
  the corrected leave-one-out error choosing the basis (Blatman & Sudret 2011);
* ``"omp"``: the same with orthogonal matching pursuit as the path (greedy: the column
  most correlated with the residual enters, then OLS), which finds exactly sparse
  expansions from fewer runs (Ishigami: 1e-8 index errors from 100 runs).

Both sparse methods raise the candidate degree one by one, run the path on the candidate
set of that degree, refit every nested active set by OLS and score it with the corrected
leave-one-out error. By default (``q_norm=None``) the candidate sets are hyperbolic ones
for q in (0.5, 0.75, 1), each q a chain of degrees with its own early stop, tried while
affordable (:mod:`ecfm_uq.chaos.regression.adaptive`); with a given ``q_norm`` the v0.3 selection
runs on that one q, stopping after ``early_stop`` degrees without improvement. A
regression fit whose corrected LOO error exceeds 1e-2 of the output variance warns and
points at :func:`ecfm_uq.mc.sobol_indices` to check its indices by sampling.

All return the same :class:`~ecfm_uq.chaos.PolynomialChaosExpansion` as the stochastic
Galerkin solver, with ``.diagnostics`` saying what was done. Model evaluations go through
:func:`ecfm_uq.executor.evaluate_samples`, the executor path Monte Carlo uses too
(threads, processes or a ``dask.distributed`` client), with a progress bar on request.
"""

from __future__ import annotations

import itertools
import math
import time
import warnings

import numpy as np
import scipy.linalg as sla

from .._validation import as_finite_array, check_choice, check_int, rng_from_seed
from ..executor import NonFiniteOutputError, evaluate_samples
from ..memory import check_allocation
from .basis import ChaosBasis
from .germs import as_germs
from .inputs import as_inputs, check_moments
from .pce import PolynomialChaosExpansion
from .pce_options import UNSET, method_options
from .projection import project
from .quadrature import clenshaw_curtis, gauss_legendre
from .regression import fit_sparse

__all__ = ["fit_pce", "sample_design", "smolyak_rule"]

METHODS = ("quadrature", "smolyak", "lstsq", "lars", "omp")
DESIGNS = ("lhs", "sobol", "halton", "random")
RULES = ("gauss", "clenshaw-curtis")


# --------------------------------------------------------------------------------------
# designs and rules
# --------------------------------------------------------------------------------------
def sample_design(n, dim, design="lhs", seed=None):
    """``n`` germ points in [0, 1]^dim from a space-filling or random design.

    Parameters
    ----------
    n, dim : int
    design : {"lhs", "sobol", "halton", "random"}
        ``"lhs"``: ``scipy.stats.qmc.LatinHypercube``; ``"sobol"``: scrambled
        ``qmc.Sobol`` (balanced when ``n`` is a power of 2); ``"halton"``: scrambled
        ``qmc.Halton``; ``"random"``: independent uniforms.
    seed : None, int or numpy.random.Generator

    Returns
    -------
    (n, dim) ndarray
    """
    from scipy.stats import qmc

    n = check_int("n_samples", n, minimum=1)
    dim = check_int("dim", dim, minimum=1)
    design = check_choice("design", design, DESIGNS)
    rng = rng_from_seed("seed", seed)
    if design == "random":
        return rng.random((n, dim))
    if design == "lhs":
        return qmc.LatinHypercube(dim, rng=rng).random(n)
    if design == "halton":
        return qmc.Halton(dim, rng=rng).random(n)
    with warnings.catch_warnings():
        # the balance warning for n not a power of 2: the points are still valid
        warnings.simplefilter("ignore", UserWarning)
        return qmc.Sobol(dim, rng=rng).random(n)


def _design_to_germ(u, germs):
    """Design points in [0, 1]^dim to germ points: each germ's inverse CDF (uniform: as is)."""
    for d, g in enumerate(germs):
        if g.family != "legendre":
            ud = np.clip(u[:, d], np.finfo(float).tiny, 1.0 - np.finfo(float).epsneg)
            u[:, d] = g.ppf(ud)
    return u


def _rule_1d(rule, level):
    """1-D rule of a Smolyak level (1-based) and the degree its projection is exact for."""
    if rule == "gauss":
        x, w = gauss_legendre(level)
        return x, w, level - 1
    n = 1 if level == 1 else 2 ** (level - 1) + 1
    x, w = clenshaw_curtis(n)
    return x, w, (n - 1) // 2


def _smolyak_levels(level, dim):
    """Multi-levels l (1-based) of the Smolyak formula and their combination coefficients.

    .. math:: A(q, d) = \\sum_{q - d + 1 \\le |l| \\le q} (-1)^{q - |l|}
              \\binom{d - 1}{q - |l|} \\bigotimes_i U^{l_i}, \\qquad q = \\ell + d.
    """
    q = level + dim
    out = []
    for l in itertools.product(range(1, level + 2), repeat=dim):
        s = sum(l)
        if q - dim + 1 <= s <= q:
            out.append((l, (-1) ** (q - s) * math.comb(dim - 1, q - s)))
    return out


def smolyak_rule(level, dim, rule="gauss", germs=None):
    """Distinct nodes of a Smolyak sparse grid and the tensor rules that make it.

    Parameters
    ----------
    level : int
        Smolyak level :math:`\\ell \\ge 0` (``level = 0`` is the one-point rule).
    dim : int
    rule : {"gauss", "clenshaw-curtis"}
        1-D rules: Gauss-Legendre with ``l`` points at level ``l`` (not nested; only the
        midpoint is shared) or Clenshaw-Curtis with :math:`2^{l-1} + 1` points (nested).
    germs : sequence of Germ, optional
        The germ of each variable (default uniform). A non-uniform germ uses its own
        ``l``-point Gauss rule at level ``l`` and needs ``rule="gauss"``.

    Returns
    -------
    nodes : (n, dim) ndarray
        Distinct germ nodes (a shared node appears once: it is evaluated once).
    parts : list of (coef, levels, index, weights, degrees)
        One tensor rule per multi-level: combination coefficient, levels, positions of
        its nodes in ``nodes``, its tensor weights and its 1-D exact degrees.
    """
    level = check_int("order", level, minimum=0)
    dim = check_int("dim", dim, minimum=1)
    rule = check_choice("rule", rule, RULES)
    germs = as_germs(germs, dim)
    if rule != "gauss" and any(g.family != "legendre" for g in germs):
        raise ValueError(
            f"`rule`={rule!r} (nested Clenshaw-Curtis on [0, 1]) is for uniform inputs; the "
            f"germs {list(germs)} need rule='gauss' (each germ's own Gauss rule)"
        )
    shared = {l: _rule_1d(rule, l) for l in range(1, level + 2)}

    def germ_rule(g, l):
        if g.family == "legendre":
            return shared[l]
        x, w = g.gauss(l)
        return x, w, l - 1

    rules = [{l: germ_rule(g, l) for l in range(1, level + 2)} for g in germs]
    keys = {}
    all_nodes = []
    parts = []
    for l, coef in _smolyak_levels(level, dim):
        if coef == 0:
            continue
        grids = np.meshgrid(*[rules[d][li][0] for d, li in enumerate(l)], indexing="ij")
        pts = np.stack([g.ravel() for g in grids], axis=1)
        w = np.ones(1)
        for d, li in enumerate(l):
            w = np.outer(w, rules[d][li][1]).ravel()
        idx = np.empty(len(pts), dtype=np.int64)
        for j, p in enumerate(np.round(pts, 13)):
            key = tuple(p.tolist())
            if key not in keys:
                keys[key] = len(all_nodes)
                all_nodes.append(pts[j])
            idx[j] = keys[key]
        parts.append((coef, l, idx, w, tuple(rules[d][li][2] for d, li in enumerate(l))))
    return np.array(all_nodes).reshape(-1, dim), parts


# --------------------------------------------------------------------------------------
# model evaluations through the executor path
# --------------------------------------------------------------------------------------
def _evaluate(model, x, executor, workers, progress, label, check=None):
    """``model`` at each row of ``x`` through :func:`ecfm_uq.executor.evaluate_samples`."""
    if not callable(model):
        raise TypeError(f"`model` must be callable model(x) -> array, got {type(model).__name__}")
    bar, own_bar = None, False
    if callable(getattr(progress, "update", None)):
        bar = progress  # the caller's bar (e.g. a tqdm), updated but not closed here
    elif progress:
        from tqdm.auto import tqdm

        bar, own_bar = tqdm(total=len(x), desc=f"fit_pce ({label})", leave=False), True
    try:
        return evaluate_samples(
            model,
            x,
            executor,
            workers=workers,
            callback=None if bar is None else bar.update,
            name="model",
            check=check,
        )
    except NonFiniteOutputError as e:
        point = np.array2string(x[e.index], precision=6)
        raise ValueError(
            f"`model` returned NaN or inf at {label} point {e.index} (x={point}); check the "
            "model there (a PCE cannot be fitted to non-finite outputs)"
        ) from e
    finally:
        if own_bar:
            bar.close()


# --------------------------------------------------------------------------------------
# methods
# --------------------------------------------------------------------------------------
def _fit_quadrature(model, inputs, order, n_points, index_set, ev):
    dim = inputs.dim
    order = check_int("order", 3 if order is None else order, minimum=0)
    n_points = (
        order + 1 if n_points is None else check_int("options['n_points']", n_points, minimum=1)
    )
    basis = ChaosBasis(order, dim, index_set=index_set or "tensor", germ=inputs.germs)
    n_nodes, P = n_points**dim, basis.size
    check_allocation(
        8.0 * 2 * n_nodes * P,
        f"the projection of {n_nodes} tensor Gauss nodes onto P = {P} terms (order {order}, "
        f"{dim} inputs)",
        "use method='smolyak' (a sparse grid, far fewer nodes), index_set='total', or a "
        "smaller `order` or `n_points`",
    )
    nodes, w = basis.quadrature(n_points)
    y = ev(inputs.from_germ(nodes), "Gauss")
    pce = PolynomialChaosExpansion(basis, project(basis, nodes, w, y), inputs)
    rule = "tensor Gauss-Legendre" if basis.is_legendre else "tensor Gauss (germ rules)"
    pce.diagnostics.update(n_points=n_points, rule=rule)
    return pce, len(nodes)


def _fit_smolyak(model, inputs, order, rule, ev):
    dim = inputs.dim
    level = check_int("order", 3 if order is None else order, minimum=0)
    rule = check_choice("rule", rule, RULES)
    nodes, parts = smolyak_rule(level, dim, rule, inputs.germs)
    y = ev(inputs.from_germ(nodes), "sparse-grid")
    out_shape = y.shape[1:]
    # the union of the tensor sets, inside the smallest total-degree basis holding it
    max_total = max(sum(deg) for _, _, _, _, deg in parts)
    basis = ChaosBasis(max_total, dim, index_set="total", germ=inputs.germs)
    lookup = {tuple(a): k for k, a in enumerate(basis.indices.tolist())}
    c = np.zeros((basis.size, int(np.prod(out_shape, dtype=int))))
    yf = y.reshape(len(nodes), -1)
    for coef, _, idx, w, deg in parts:
        tb = ChaosBasis(max(deg), dim, index_set="tensor", germ=inputs.germs)
        keep = np.all(tb.indices <= np.array(deg), axis=1)
        Psi = tb.evaluate(nodes[idx])[:, keep]
        ck = (Psi * w[:, None]).T @ yf[idx]
        rows = [lookup[tuple(a)] for a in tb.indices[keep].tolist()]
        c[rows] += coef * ck
    c = c.reshape((basis.size, *out_shape))
    pce = PolynomialChaosExpansion(basis, c, inputs)
    pce.diagnostics.update(
        rule=f"Smolyak level {level} on {rule} ({'nested' if rule != 'gauss' else 'not nested'})",
        tensor_rules=len(parts),
    )
    return pce, len(nodes)


def _regression_data(model, inputs, n_samples, samples, evaluations, design, seed, P, ev):
    """Germ points and outputs for regression (given or generated and evaluated)."""
    dim = inputs.dim
    if samples is not None:
        x = as_finite_array("samples", samples)
        if x.ndim == 1 and dim == 1:
            x = x[:, None]
        if x.ndim != 2 or x.shape[1] != dim:
            raise ValueError(f"`samples` must have shape (n, {dim}), got {x.shape}")
        omega = inputs.to_germ(x)
        name = "samples"
    else:
        n = 2 * P if n_samples is None else check_int("n_samples", n_samples, minimum=1)
        omega = _design_to_germ(sample_design(n, dim, design, seed), inputs.germs)
        x = inputs.from_germ(omega)
        name = "n_samples"
    if evaluations is not None:
        y = as_finite_array("evaluations", evaluations)
        if y.ndim == 0 or y.shape[0] != len(x):
            raise ValueError(
                f"`evaluations` must have shape (n, *output_shape) with n = {len(x)} rows, "
                f"one per sample, got {y.shape}"
            )
    else:
        y = None
    return omega, x, y, name


def _fit_lstsq(model, inputs, order, index_set, data, ev):
    dim = inputs.dim
    order = check_int("order", 3 if order is None else order, minimum=0)
    basis = ChaosBasis(order, dim, index_set=index_set or "total", germ=inputs.germs)
    P = basis.size
    omega, x, y, name = data(P)
    n = len(omega)
    if n <= P:
        raise ValueError(
            f"too few regression samples: `{name}` gives {n} points for P = {P} basis terms "
            f"(order {order}, dim {dim}); least squares needs more than P (about 2P = {2 * P} "
            "is the usual choice), or lower `order`"
        )
    check_allocation(
        8.0 * (3 * n * P + 2 * P * P),
        f"least squares on n = {n} runs by P = {P} terms (order {order}, {dim} inputs)",
        "pass a smaller `order`, or use method='lars' (candidates sized by the memory budget)",
    )

    def check_outputs(n_runs, out_shape):
        """Before the other runs: the residuals and leave-one-out terms of every output."""
        m = math.prod(out_shape)
        check_allocation(
            8.0 * (3 * n * P + 2 * P * P + 4 * n * m + 3 * P * m),
            f"least squares on n = {n} runs by P = {P} terms for a {m}-value output",
            "let the model return fewer output values, or use method='lars' (a field is "
            "compressed to a few principal components first)",
        )

    if y is None:
        y = ev(x, "regression", check_outputs)
    else:
        check_outputs(n, y.shape[1:])
    Psi = basis.evaluate(omega)
    Q, R = sla.qr(Psi, mode="economic")
    if np.min(np.abs(np.diag(R))) < 1e-12 * np.max(np.abs(np.diag(R))):
        raise ValueError(
            f"the design matrix at `{name}` is rank-deficient for order {order}; use more "
            "or better spread samples (design='lhs' or 'sobol')"
        )
    yf = y.reshape(n, -1)
    z = Q.T @ yf
    c = sla.solve_triangular(R, z)
    resid = yf - Q @ z
    h = np.sum(Q**2, axis=1)
    var = np.var(yf, axis=0)
    var = np.where(var > 0, var, 1.0)
    loo = np.mean((resid / (1.0 - h)[:, None]) ** 2, axis=0) / var
    trace = np.sum(sla.solve_triangular(R, np.eye(P)) ** 2)
    corr = n / (n - P) * (1.0 + trace)
    pce = PolynomialChaosExpansion(basis, c.reshape((P, *y.shape[1:])), inputs)
    pce.diagnostics.update(
        design=None if name == "samples" else data.design,
        loo_error=loo.reshape(y.shape[1:]),
        corrected_loo_error=(loo * corr).reshape(y.shape[1:]),
    )
    return pce, n


# --------------------------------------------------------------------------------------
# public entry point
# --------------------------------------------------------------------------------------
def fit_pce(
    model,
    inputs,
    method="lars",
    order=None,
    *,
    n_samples=None,
    samples=None,
    evaluations=None,
    options=None,
    executor=None,
    workers=1,
    seed=None,
    progress=False,
    design=UNSET,
    index_set=UNSET,
    n_points=UNSET,
    rule=UNSET,
    q_norm=UNSET,
    early_stop=UNSET,
    compress=UNSET,
    compress_tol=UNSET,
):
    """A polynomial chaos expansion of a black-box model from its evaluations.

    Parameters
    ----------
    model : callable
        ``model(x) -> array_like`` of a fixed shape (scalar, vector or field), ``x`` a
        (dim,) point on the inputs' own ranges. It must be picklable to run in worker
        processes (a module-level function or ``functools.partial`` of one). May be
        ``None`` when ``evaluations`` are given.
    inputs : UniformInputs, (dim, 2) bounds or chaospy distribution
        Independent uniform inputs :math:`x_k \\sim \\mathcal U(a_k, b_k)` as bounds;
        any continuous inputs as an :class:`~ecfm_uq.chaos.Inputs` (marginals and an
        optional Gaussian-copula correlation), a list of scipy.stats frozen distributions,
        a chaospy distribution (``J``, ``Iid``, ``MvNormal``) or a
        ``scipy.stats.multivariate_normal``. The design is drawn (and the quadrature rule
        built) in the germ variables: each input's Askey germ, or standard normals for
        transformed and dependent inputs.
    method : {"lars", "omp", "lstsq", "quadrature", "smolyak"}
        See the module docstring. Default ``"lars"``.
    order : int, optional
        ``"quadrature"``: degree per variable (default 3); ``"smolyak"``: the level
        :math:`\\ell` (total degree :math:`\\ell` for ``rule="gauss"``; default 3);
        ``"lstsq"``: total degree (default 3); ``"lars"``, ``"omp"``: the largest
        candidate degree (default: the largest whose basis has at most ``10 n`` terms,
        at most 30).
    n_samples : int, optional
        Regression design size (default ``2 P`` for ``"lstsq"``, 100 for the sparse
        methods).
    samples : (n, dim) array_like, optional
        Regression points on the inputs' ranges instead of a generated design.
    evaluations : (n, *output_shape) array_like, optional
        Model outputs at ``samples`` (then the model is not called).
    options : dict, optional
        The method's settings by name (:mod:`ecfm_uq.chaos.pce_options`); a name the
        method does not read is refused (``TypeError`` naming those it does) before any
        model run. The v0.4 spelling, each a keyword of ``fit_pce`` (``q_norm=0.75``),
        works for this release with a ``DeprecationWarning``.

        ``"design"`` : {"lhs", "sobol", "halton", "random"}
            ``"lstsq"``, ``"lars"``, ``"omp"``: the generated regression design
            (``scipy.stats.qmc``). Default Latin hypercube.
        ``"index_set"`` : {"total", "tensor"}
            ``"quadrature"``, ``"lstsq"`` (and ``"total"`` only for the sparse methods):
            the basis truncation (default ``"tensor"`` for quadrature, ``"total"`` else).
        ``"n_points"`` : int
            ``"quadrature"``: Gauss points per variable (default ``order + 1``).
        ``"rule"`` : {"gauss", "clenshaw-curtis"}
            ``"smolyak"``: the 1-D rules of the grid, Gauss-Legendre (not nested, the
            default) or Clenshaw-Curtis (nested).
        ``"q_norm"`` : float or None
            Sparse methods. ``None`` (default): adaptive truncation
            (:mod:`ecfm_uq.chaos.regression.adaptive`): for each q in (0.5, 0.75, 1) a
            chain of hyperbolic candidate sets :math:`\\|\\alpha\\|_q \\le p`, p = 1, 2,
            ..., while affordable and improving the corrected LOO error; the result keeps
            the selected terms only, and ``diagnostics`` says what was chosen
            (``degree``, ``q_norm``, ``n_candidates``, ``adaptive_trace`` of (degree, q,
            candidates, error)). A number in (0, 1]: the v0.3 selection on that fixed q
            up to the candidate degree (1 = total degree).
        ``"early_stop"`` : int
            Sparse methods: stop raising the degree (of each q chain) after this many
            degrees without improvement (default 2).
        ``"compress"`` : bool, "exact" or "randomized"
            Sparse methods on a field output: select on the leading principal components
            of the evaluations instead of on every component (PCA-PCE, Blatman & Sudret
            2013), so a 10 000-value field costs about what a scalar does. Default: for
            outputs of more than 64 components. ``True`` computes them by the exact SVD
            when it fits the memory budget and by a randomized SVD in blocks (Halko,
            Martinsson & Tropp 2011; the evaluations held once) otherwise, and when even
            the evaluations do not fit, compresses them as they arrive by a one-pass
            sketch (Tropp et al. 2017; the discarded share then estimated,
            ``compression="streaming"``); ``"exact"`` or ``"randomized"`` forces one.
            ``diagnostics`` then holds ``n_components``, ``compression`` (which SVD
            ran), ``compression_info``, ``compression_error`` (per output component, its
            discarded variance over its variance; measured on the data for the
            randomized SVD) beside ``corrected_loo_error`` (per component, the scores'
            errors mapped onto it plus the compression's).
        ``"compress_tol"`` : float
            Sparse methods: the largest share of any component's variance the
            compression may discard (default 1e-6).
    executor : object with ``map``, optional
        As in :func:`ecfm_uq.mc.monte_carlo`: a ``ThreadPoolExecutor``,
        ``ProcessPoolExecutor`` or ``dask.distributed.Client``.
    workers : int
        Processes of a pool created here when no ``executor`` is given (1: in-process).
    seed : None, int or Generator
        Seeds the generated design.
    progress : bool or object with ``update(n)``
        ``True``: show a tqdm progress bar over the model evaluations; or the caller's
        own bar (e.g. a ``tqdm``), advanced by the number of finished runs.
    design, index_set, n_points, rule, q_norm, early_stop, compress, compress_tol
        Deprecated: pass them in ``options``.

    Returns
    -------
    PolynomialChaosExpansion
        With ``diagnostics``: ``method``, ``n_evaluations``, ``wall_time``, and
        ``loo_error`` / ``corrected_loo_error`` (regression; relative to the output
        variance, per output component), ``degree`` and ``n_terms`` (sparse methods),
        ``poor_fit`` (regression: the corrected LOO error exceeds 1e-2 of the variance;
        a ``RuntimeWarning`` then points at :func:`ecfm_uq.mc.sobol_indices`).

    Raises
    ------
    ValueError
        Unknown method or design, too few regression samples for the basis (naming
        ``n_samples`` or ``samples``), a model output that is NaN or inf (naming the
        point), outputs of different shapes, ``evaluations`` not matching ``samples``;
        an input law without a finite mean (Cauchy, Pareto with shape <= 1) or a user's
        density that does not integrate to 1; a negative ``seed``.
    TypeError
        ``model`` not callable or returning ``None``, a tuple, complex values; a discrete
        input distribution; a seed that is not one; an option the method does not read
        (naming those it does), ``options`` not a dict, an option given twice.
    Exception
        An exception of ``model``, as its own type, naming the point it was called at
        (the original chained).

    Examples
    --------
    >>> import numpy as np
    >>> f = lambda x: x[0] + x[1] ** 2
    >>> pce = fit_pce(f, [(0, 1), (-1, 1)], method="quadrature", order=2)
    >>> round(float(pce.mean), 6), pce.first_order().round(6).tolist()
    (0.833333, [0.483871, 0.516129])
    """
    t0 = time.perf_counter()
    method = check_choice("method", method, METHODS)
    # the method's settings, checked by name (the v0.4 keywords: deprecated, still taken)
    opts = method_options(method, options, dict(
        design=design, index_set=index_set, n_points=n_points, rule=rule, q_norm=q_norm,
        early_stop=early_stop, compress=compress, compress_tol=compress_tol))  # fmt: skip
    inputs = as_inputs(inputs)
    if inputs is None:
        raise TypeError("`inputs` must be given: bounds (dim, 2), UniformInputs or chaospy.J")
    # the expansion's mean is the law's: it must exist (the variance is checked where it
    # is used, by the Sobol indices, so an output free of a heavy-tailed input keeps them)
    check_moments(inputs, "fit_pce", variance=False)
    workers = check_int("workers", workers, minimum=1)
    if model is None and evaluations is None:
        raise TypeError("`model` must be callable (or pass `samples` and `evaluations`)")
    for name, value in (("samples", samples), ("evaluations", evaluations)):
        if value is not None and method in ("quadrature", "smolyak"):
            raise ValueError(
                f"`{name}` are for regression methods; method={method!r} picks its own "
                "nodes (use method='lstsq', 'lars' or 'omp' with given samples)"
            )
    if evaluations is not None and samples is None:
        raise ValueError("`evaluations` need the `samples` they were computed at")

    def ev(x, label, check=None):
        return _evaluate(model, x, executor, workers, progress, label, check)

    def data(P):
        n_default = 100 if P is None else 2 * P
        return _regression_data(
            model,
            inputs,
            n_default if n_samples is None else n_samples,
            samples,
            evaluations,
            data.design,
            seed,
            P,
            ev,
        )

    if "design" in opts:
        data.design = check_choice("options['design']", opts["design"], DESIGNS)
    if method == "quadrature":
        pce, n_eval = _fit_quadrature(model, inputs, order, opts["n_points"], opts["index_set"], ev)
    elif method == "smolyak":
        pce, n_eval = _fit_smolyak(model, inputs, order, opts["rule"], ev)
    elif method == "lstsq":
        pce, n_eval = _fit_lstsq(model, inputs, order, opts["index_set"], data, ev)
    else:
        q_norm, early_stop = opts["q_norm"], opts["early_stop"]
        compress, compress_tol = opts["compress"], opts["compress_tol"]
        if q_norm is not None and (isinstance(q_norm, bool) or not 0 < float(q_norm) <= 1):
            raise ValueError(
                f"options['q_norm'] must be None (adaptive) or lie in (0, 1], got {q_norm!r}"
            )
        early_stop = check_int("options['early_stop']", early_stop, minimum=1)
        if isinstance(compress, np.bool_):
            compress = bool(compress)
        if compress is not None and not (
            isinstance(compress, bool)
            or (isinstance(compress, str) and compress in ("exact", "randomized"))
        ):
            raise TypeError(
                f"options['compress'] must be None, True, False, 'exact' or 'randomized', got "
                f"{compress!r}"
            )
        if isinstance(compress_tol, bool) or not 0 <= float(compress_tol) < 1:
            raise ValueError(f"options['compress_tol'] must lie in [0, 1), got {compress_tol!r}")
        basis, c, diagnostics, n_eval = fit_sparse(
            inputs,
            order,
            opts["index_set"],
            data,
            ev,
            None if q_norm is None else float(q_norm),
            early_stop,
            method,
            compress,
            float(compress_tol),
            ChaosBasis,
        )
        pce = PolynomialChaosExpansion(basis, c, inputs)
        pce.diagnostics.update(diagnostics)
    pce.diagnostics.update(
        method=method,
        n_evaluations=n_eval,
        wall_time=time.perf_counter() - t0,
    )
    _warn_if_poor(pce)
    # an input's variance check is computed once, here (a custom law's variance is a
    # numerical integral of up to seconds), so the indices of the fit cost milliseconds
    for m in getattr(inputs, "marginals", ()):
        m.finite_variance  # noqa: B018  (a cached property: computing it is the point)
    return pce


# A corrected leave-one-out error above this share of the output variance: the expansion
# misses that share, and its Sobol indices can be off by about as much.
POOR_LOO_ERROR = 1e-2


def _warn_if_poor(pce):
    """Say so when a regression fit's corrected LOO error is poor, and how to check it."""
    err = pce.diagnostics.get("corrected_loo_error")
    if err is None:
        return
    worst = float(np.max(err)) if np.size(err) else 0.0
    pce.diagnostics["poor_fit"] = bool(worst > POOR_LOO_ERROR)
    if worst > POOR_LOO_ERROR:
        warnings.warn(
            f"fit_pce: the corrected leave-one-out error is {worst:.1e} of the output "
            f"variance (> {POOR_LOO_ERROR:g}): the expansion misses that share and its Sobol "
            "indices may be off by about as much. Add runs (n_samples), or check the indices "
            "by sampling: ecfm_uq.mc.sobol_indices(model, inputs, n=2**12, seed=0)",
            RuntimeWarning,
            stacklevel=3,
        )
