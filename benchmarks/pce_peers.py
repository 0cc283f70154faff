"""Non-intrusive PCE and Sobol indices: ecfm_uq against chaospy and OpenTURNS, one run.

Four analytic benchmarks with closed-form indices:

* Ishigami, a = 7, b = 0.1, x ~ U(-pi, pi)^3;
* Sobol' g-function, d = 6, a = (0, 1, 4.5, 9, 99, 99), x ~ U(0, 1)^6;
* short column (Kuschel & Rackwitz 1997), g = 1 - 4M/(b h^2 Y) - P^2/(b^2 h^2 Y^2),
  b = 5, h = 15, with normal M ~ N(2000, 400), P ~ N(500, 100) and lognormal yield stress
  Y (mean 5, c.o.v. 0.1), independent: a standard engineering function with normal and
  lognormal inputs;
* gamma-beta-lognormal, y = x1 + x2^2 + x1 x3 with x1 ~ Gamma(2), x2 ~ Beta(2, 3),
  x3 ~ LogNormal(0.25).

The last two are product-sum models of independent inputs, so their mean, variance and
every Sobol index follow in closed form from the inputs' raw moments (``product_sum``).
On them ours runs on Hermite / Laguerre / Jacobi germs (lognormal through the
isoprobabilistic transform); OpenTURNS is run twice on the same designs: with each
marginal's own orthonormal family (``StandardDistributionPolynomialFactory``, its default)
and with Hermite polynomials plus its isoprobabilistic transform.

At budgets of about 100, 500 and 1 000 model evaluations, each method reports the
relative errors of mean and variance, the largest first-order or total index error
against the analytic values, and its wall time (fit plus indices; single thread).

Methods (regression methods all see the *same* Latin hypercube designs, median over
``--designs`` seeds; quadrature rules are deterministic):

* ours  ``fit_pce(method="lars")`` and ``fit_pce(method="omp")``: hybrid LARS / orthogonal
  matching pursuit, corrected LOO, degree-adaptive (defaults, nothing tuned);
* ours  ``fit_pce(method="quadrature")``: tensor Gauss-Legendre, (k+1)^d <= budget;
* ours  ``fit_pce(method="smolyak")``: Smolyak on Gauss-Legendre, nodes <= budget;
* chaospy tensor Gauss quadrature (``generate_quadrature(rule="gaussian")`` +
  ``fit_quadrature``), same node counts as ours;
* chaospy point collocation (``fit_regression``, OLS, total order with P <= n/3);
* chaospy + scikit-learn ``LarsCV(fit_intercept=False)`` (total order with P <= n);
* OpenTURNS ``FunctionalChaosAlgorithm``: Legendre up to total degree 14 (Ishigami) or
  the largest with P <= 2n (g), ``LARS`` + ``CorrectedLeaveOneOut``.

chaospy's indices are read off its (orthonormal) coefficients with the same formula as
ours, because ``chaospy.Sens_m``/``Sens_t`` take seconds to minutes at these orders;
their cost is measured separately at order 4 and reported. OpenTURNS' indices come
from its own ``FunctionalChaosSobolIndices``.

Issue 30 parts:

* ``--part mixed``: eight inputs of mixed laws (a truncated Gumbel written as an
  ``rv_continuous`` subclass, a normal truncated below, three uniforms, two triangulars,
  a lognormal) and a non-polynomial model with interactions, whose indices follow from
  one-dimensional integrals (``mixed_reference``); at N = 100, 300, 1000 ours with every
  default (``Inputs`` from the scipy laws, ``fit_pce``, indices) against OpenTURNS'
  sparse chaos (its own polynomials per marginal, hyperbolic q = 0.5 up to degree 10 as in
  its ResourceMap, LARS + corrected LOO), on the same designs: median largest index error
  and median time over ``--designs`` designs, and their ratios;
* ``--part sampling``: the 20-input g-function by ``ecfm_uq.mc.sobol_indices`` at
  n = 2^13 against its analytic indices (largest error, interval coverage over seeds).

Run: ``python benchmarks/pce_peers.py [--designs 3] [--quick] [--part all|analytic|mixed|sampling]``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402
from scipy.stats import qmc  # noqa: E402

from ecfm_uq.chaos import Inputs, fit_pce, smolyak_rule  # noqa: E402

# the truncated Gumbel of --part mixed is the user's own law the tests check (tests/_laws.py)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _laws import TRUNC_GUMBEL  # noqa: E402

PI = np.pi
BUDGETS = (100, 500, 1000)


# --------------------------------------------------------------------------------------
# problems with closed-form indices
# --------------------------------------------------------------------------------------
class Ishigami:
    name = "ishigami"
    dim = 3
    a, b = 7.0, 0.1
    bounds = np.array([(-PI, PI)] * 3)

    def __call__(self, x):
        return np.sin(x[0]) + self.a * np.sin(x[1]) ** 2 + self.b * x[2] ** 4 * np.sin(x[0])

    def batch(self, X):
        return (
            np.sin(X[:, 0])
            + self.a * np.sin(X[:, 1]) ** 2
            + self.b * X[:, 2] ** 4 * np.sin(X[:, 0])
        )

    def reference(self):
        a, b = self.a, self.b
        V = a**2 / 8 + b * PI**4 / 5 + b**2 * PI**8 / 18 + 0.5
        V1 = (1 + b * PI**4 / 5) ** 2 / 2
        V2 = a**2 / 8
        V13 = b**2 * PI**8 * (1 / 18 - 1 / 50)
        return a / 2, V, np.array([V1, V2, 0.0]) / V, np.array([V1 + V13, V2, V13]) / V

    def ot_degree(self, n):
        return 14


class SobolG:
    name = "sobol-g"
    dim = 6
    A = np.array([0.0, 1.0, 4.5, 9.0, 99.0, 99.0])
    bounds = np.array([(0.0, 1.0)] * 6)

    def __call__(self, x):
        return np.prod((np.abs(4 * x - 2) + self.A) / (1 + self.A))

    def batch(self, X):
        return np.prod((np.abs(4 * X - 2) + self.A) / (1 + self.A), axis=1)

    def reference(self):
        Vi = 1 / (3 * (1 + self.A) ** 2)
        V = np.prod(1 + Vi) - 1
        T = np.array([Vi[i] * np.prod(np.delete(1 + Vi, i)) for i in range(6)]) / V
        return 1.0, V, Vi / V, T

    def ot_degree(self, n):
        p = 1
        while math.comb(p + 1 + 6, 6) <= 2 * n:
            p += 1
        return p


def product_sum(c0, terms, moment, dim):
    """Mean, variance, first-order and total indices of y = c0 + sum_t c_t prod_v x_v^k.

    ``terms`` = [(c_t, {v: k})], ``moment(v, k)`` = E[x_v^k]; independent inputs, so
    E[y | x_S] replaces the factors outside S by their means.
    """

    def cond_var(S):
        mean = c0 + sum(c * math.prod(moment(v, k) for v, k in pw.items()) for c, pw in terms)
        second = 0.0
        for ci, pi in terms:
            for cj, pj in terms:
                val = ci * cj
                for v in set(pi) | set(pj):
                    ki, kj = pi.get(v, 0), pj.get(v, 0)
                    val *= moment(v, ki + kj) if v in S else moment(v, ki) * moment(v, kj)
                second += val
        return second - (mean - c0) ** 2, mean

    full = set(range(dim))
    V, mean = cond_var(full)
    S = np.array([cond_var({i})[0] for i in range(dim)]) / V
    T = np.array([1.0 - cond_var(full - {i})[0] / V for i in range(dim)])
    return mean, V, S, T


class ShortColumn:
    name = "short-col"
    dim = 3
    b, h = 5.0, 15.0
    sY = math.sqrt(math.log(1 + 0.1**2))
    mY = math.log(5.0) - sY**2 / 2

    @property
    def inputs(self):
        return [stats.norm(2000.0, 400.0), stats.norm(500.0, 100.0), self._Y()]

    def _Y(self):
        return stats.lognorm(self.sY, scale=math.exp(self.mY))

    def __call__(self, x):
        return self.batch(np.asarray(x)[None, :])[0]

    def batch(self, X):
        M, P, Y = X.T
        return 1 - 4 * M / (self.b * self.h**2 * Y) - P**2 / (self.b**2 * self.h**2 * Y**2)

    def reference(self):
        laws = self.inputs

        def moment(v, k):
            if k == 0:
                return 1.0
            if v == 2:  # U = 1/Y is lognormal too: E[U^k] = exp(-k mu + k^2 s^2 / 2)
                return math.exp(-k * self.mY + k * k * self.sY**2 / 2)
            return float(laws[v].moment(k))

        bh = self.b * self.h
        terms = [(-4 / (bh * self.h), {0: 1, 2: 1}), (-1 / bh**2, {1: 2, 2: 2})]
        return product_sum(1.0, terms, moment, 3)

    def cp_dist(self):
        import chaospy

        return chaospy.J(
            chaospy.Normal(2000.0, 400.0),
            chaospy.Normal(500.0, 100.0),
            chaospy.LogNormal(self.mY, self.sY),
        )

    def ot_marginals(self, ot):
        return [ot.Normal(2000.0, 400.0), ot.Normal(500.0, 100.0), ot.LogNormal(self.mY, self.sY)]

    def ot_degree(self, n):
        return 10


class GammaBetaLognormal:
    name = "gam-beta-ln"
    dim = 3

    @property
    def inputs(self):
        return [stats.gamma(2.0), stats.beta(2.0, 3.0), stats.lognorm(0.25)]

    def __call__(self, x):
        return x[0] + x[1] ** 2 + x[0] * x[2]

    def batch(self, X):
        return X[:, 0] + X[:, 1] ** 2 + X[:, 0] * X[:, 2]

    def reference(self):
        laws = self.inputs

        def moment(v, k):
            return float(laws[v].moment(k)) if k else 1.0

        return product_sum(0.0, [(1.0, {0: 1}), (1.0, {1: 2}), (1.0, {0: 1, 2: 1})], moment, 3)

    def cp_dist(self):
        import chaospy

        return chaospy.J(chaospy.Gamma(2.0), chaospy.Beta(2.0, 3.0), chaospy.LogNormal(0.0, 0.25))

    def ot_marginals(self, ot):
        return [ot.Gamma(2.0, 1.0), ot.Beta(2.0, 3.0, 0.0, 1.0), ot.LogNormal(0.0, 0.25)]

    def ot_degree(self, n):
        return 10


def errors(problem, mean, var, S, T):
    m0, V0, S0, T0 = problem.reference()
    return (
        abs(mean - m0) / abs(m0),
        abs(var - V0) / V0,
        max(np.max(np.abs(np.asarray(S) - S0)), np.max(np.abs(np.asarray(T) - T0))),
    )


def lhs(problem, n, seed):
    u = qmc.LatinHypercube(problem.dim, rng=np.random.default_rng(seed)).random(n)
    if not hasattr(problem, "bounds"):  # inputs as distributions: their quantiles
        return np.column_stack([law.ppf(u[:, k]) for k, law in enumerate(problem.inputs)])
    lo, hi = problem.bounds[:, 0], problem.bounds[:, 1]
    return lo + (hi - lo) * u


def _inputs(problem):
    return problem.bounds if hasattr(problem, "bounds") else problem.inputs


# --------------------------------------------------------------------------------------
# ours
# --------------------------------------------------------------------------------------
def ours_lars(problem, X, Y):
    pce = fit_pce(None, _inputs(problem), "lars", samples=X, evaluations=Y)
    return pce.mean, pce.variance, pce.first_order(), pce.total()


def ours_omp(problem, X, Y):
    pce = fit_pce(None, _inputs(problem), "omp", samples=X, evaluations=Y)
    return pce.mean, pce.variance, pce.first_order(), pce.total()


def ours_quadrature(problem, budget):
    k = int(math.floor(budget ** (1 / problem.dim) + 1e-9)) - 1
    pce = fit_pce(problem, _inputs(problem), "quadrature", order=k)
    return (pce.mean, pce.variance, pce.first_order(), pce.total()), (k + 1) ** problem.dim


def _smolyak_level(dim, budget, germs=None):
    level = 0
    while len(smolyak_rule(level + 1, dim, germs=germs)[0]) <= budget:
        level += 1
    return level


def ours_smolyak(problem, budget):
    germs = None if hasattr(problem, "bounds") else Inputs(problem.inputs).germs
    level = _smolyak_level(problem.dim, budget, germs)
    pce = fit_pce(problem, _inputs(problem), "smolyak", order=level)
    n = pce.diagnostics["n_evaluations"]
    return (pce.mean, pce.variance, pce.first_order(), pce.total()), n


# --------------------------------------------------------------------------------------
# chaospy
# --------------------------------------------------------------------------------------
def _cp_dist(problem):
    import chaospy

    if not hasattr(problem, "bounds"):
        return problem.cp_dist()
    return chaospy.J(*[chaospy.Uniform(a, b) for a, b in problem.bounds])


def _cp_indices(expansion, coef, dim):
    """Sobol indices from an orthonormal chaospy expansion's coefficients."""
    support = np.zeros((len(expansion), dim), dtype=bool)
    for k, term in enumerate(expansion):
        nz = np.asarray(term.coefficients) != 0
        e = term.exponents[nz] if nz.ndim == 1 else term.exponents
        support[k] = (e > 0).any(axis=0)
    c2 = np.asarray(coef, dtype=float).reshape(-1) ** 2
    const = ~support.any(axis=1)
    V = c2[~const].sum()
    mean = float(np.sum(np.asarray(coef).reshape(-1)[const]))
    only = support & (support.sum(axis=1) == 1)[:, None]
    return mean, V, only.T.astype(float) @ c2 / V, support.T.astype(float) @ c2 / V


def _cp_order(dim, n, ratio):
    p = 0
    while math.comb(p + 1 + dim, dim) <= n / ratio:
        p += 1
    return p


def chaospy_quadrature(problem, budget):
    import chaospy

    dist = _cp_dist(problem)
    k = int(math.floor(budget ** (1 / problem.dim) + 1e-9)) - 1
    nodes, weights = chaospy.generate_quadrature(k, dist, rule="gaussian")
    evals = np.array([problem(x) for x in nodes.T])
    expansion = chaospy.generate_expansion(k, dist, normed=True)
    _, coef = chaospy.fit_quadrature(expansion, nodes, weights, evals, retall=1)
    return _cp_indices(expansion, coef, problem.dim), nodes.shape[1]


def chaospy_ols(problem, X, Y):
    import chaospy

    dist = _cp_dist(problem)
    expansion = chaospy.generate_expansion(_cp_order(problem.dim, len(X), 3), dist, normed=True)
    _, coef = chaospy.fit_regression(expansion, X.T, Y, retall=1)
    return _cp_indices(expansion, coef, problem.dim)


def chaospy_larscv(problem, X, Y):
    import chaospy
    from sklearn.linear_model import LarsCV

    dist = _cp_dist(problem)
    expansion = chaospy.generate_expansion(_cp_order(problem.dim, len(X), 1), dist, normed=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, coef = chaospy.fit_regression(
            expansion, X.T, Y, model=LarsCV(fit_intercept=False), retall=1
        )
    return _cp_indices(expansion, coef, problem.dim)


def chaospy_own_indices_time(problem, order=4):
    """Seconds of chaospy.Sens_m + Sens_t on an order-``order`` expansion."""
    import chaospy

    dist = _cp_dist(problem)
    X = lhs(problem, 200, 0)
    expansion = chaospy.generate_expansion(order, dist, normed=True)
    poly = chaospy.fit_regression(expansion, X.T, problem.batch(X))
    t = time.perf_counter()
    chaospy.Sens_m(poly, dist)
    chaospy.Sens_t(poly, dist)
    return time.perf_counter() - t


# --------------------------------------------------------------------------------------
# OpenTURNS
# --------------------------------------------------------------------------------------
def openturns_lars(problem, X, Y, hermite=False):
    import openturns as ot

    if hasattr(problem, "bounds"):
        dist = ot.JointDistribution([ot.Uniform(float(a), float(b)) for a, b in problem.bounds])
        factory = ot.OrthogonalProductPolynomialFactory([ot.LegendreFactory()] * problem.dim)
    else:
        marginals = problem.ot_marginals(ot)
        dist = ot.JointDistribution(marginals)
        families = (
            [ot.HermiteFactory()] * problem.dim
            if hermite
            else [ot.StandardDistributionPolynomialFactory(m) for m in marginals]
        )
        factory = ot.OrthogonalProductPolynomialFactory(families)
    P = factory.getEnumerateFunction().getBasisSizeFromTotalDegree(problem.ot_degree(len(X)))
    selection = ot.LeastSquaresMetaModelSelectionFactory(ot.LARS(), ot.CorrectedLeaveOneOut())
    algo = ot.FunctionalChaosAlgorithm(
        ot.Sample(X),
        ot.Sample(Y[:, None]),
        dist,
        ot.FixedStrategy(factory, P),
        ot.LeastSquaresStrategy(selection),
    )
    algo.run()
    result = algo.getResult()
    sens = ot.FunctionalChaosSobolIndices(result)
    S = [sens.getSobolIndex(i) for i in range(problem.dim)]
    T = [sens.getSobolTotalIndex(i) for i in range(problem.dim)]
    mean = result.getCoefficients()[0][0]
    var = sum(c[0] ** 2 for c in result.getCoefficients()[1:])
    return mean, var, S, T


# --------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------
def available(module):
    try:
        __import__(module)
        return True
    except ImportError:
        return False


class Failed(Exception):
    """A method that returns no indices (e.g. a constant output at all its nodes)."""


def timed(fn, *args):
    t = time.perf_counter()
    try:
        with np.errstate(all="ignore"):
            out = fn(*args)
    except ValueError as e:
        raise Failed(str(e)) from e
    return out, time.perf_counter() - t


def quad_row(problem, n, name, fn):
    try:
        (out, nodes), dt = timed(fn, problem, n)
    except Failed as e:
        print(f"{problem.name} n={n} {name}: no indices ({str(e)[:70]}...)")
        return None
    err = errors(problem, *out)
    if not np.all(np.isfinite(err)):
        return (problem.name, n, name, nodes, np.nan, np.nan, np.nan, dt)
    return (problem.name, n, name, nodes, *err, dt)


def run_problem(problem, designs, budgets, have):
    rows = []
    for n in budgets:
        # regression methods: the same LHS designs and evaluations for everyone
        reg = {"ours LARS": ours_lars, "ours OMP": ours_omp}
        if have["chaospy"]:
            reg["chaospy OLS"] = chaospy_ols
            if have["sklearn"]:
                reg["chaospy LarsCV"] = chaospy_larscv
        if have["openturns"]:
            reg["OpenTURNS LARS"] = openturns_lars
            if not hasattr(problem, "bounds"):
                reg["OpenTURNS LARS Hermite"] = functools.partial(openturns_lars, hermite=True)
        results = {name: [] for name in reg}
        for seed in range(designs):
            X = lhs(problem, n, seed)
            Y = problem.batch(X)
            for name, fn in reg.items():
                out, dt = timed(fn, problem, X, Y)
                results[name].append((*errors(problem, *out), dt))
        for name, rs in results.items():
            med = np.median(np.array(rs), axis=0)
            rows.append((problem.name, n, name, n, *med))
        # quadrature rules (deterministic)
        quad = {"ours tensor Gauss": ours_quadrature, "ours Smolyak Gauss": ours_smolyak}
        if have["chaospy"]:
            quad["chaospy tensor Gauss"] = chaospy_quadrature
        for name, fn in quad.items():
            row = quad_row(problem, n, name, fn)
            if row is not None:
                rows.append(row)
    return rows


def warm_up(have):
    """Imports and JIT compilation outside the timings (each tool once, tiny size)."""
    p = Ishigami()
    X = lhs(p, 40, 99)
    Y = p.batch(X)
    ours_lars(p, X, Y)
    ours_omp(p, X, Y)
    ours_quadrature(p, 30)
    if have["chaospy"]:
        chaospy_ols(p, X, Y)
        chaospy_quadrature(p, 30)
        if have["sklearn"]:
            chaospy_larscv(p, X, Y)
    if have["openturns"]:
        openturns_lars(p, X, Y)


# --------------------------------------------------------------------------------------
# eight inputs of mixed laws (issue 30): a truncated Gumbel written as an rv_continuous
# subclass, a normal truncated below, uniforms, triangulars and a lognormal
# --------------------------------------------------------------------------------------
def mixed_marginals():
    return [
        TRUNC_GUMBEL(),
        stats.truncnorm(-4.0, np.inf, loc=30.0, scale=7.5),
        stats.uniform(0.0, 1.0),
        stats.uniform(-1.0, 2.0),
        stats.triang(0.3, loc=0.0, scale=1.0),
        stats.triang(0.7, loc=1.0, scale=2.0),
        stats.uniform(0.0, 2.0),
        stats.lognorm(0.25),
    ]


def _sin15(x):
    return np.sin(1.5 * x)


def _exp08(x):
    return np.exp(0.8 * x)


def _identity(x):
    return x


def _square(x):
    return x**2


def _inverse1p(x):
    return 1.0 / (1.0 + x)


# y = sum_t c_t prod_v f_tv(x_v): non-polynomial, with interactions; its indices follow
# from one-dimensional integrals of the laws (scipy.integrate.quad on each density)
MIXED_TERMS = [
    (0.25, {0: np.log, 1: np.sqrt}),
    (2.0, {3: _sin15, 2: _identity}),
    (1.0, {4: _exp08}),
    (1.0, {5: _square, 6: np.cos}),
    (0.5, {7: _identity, 2: _identity}),
    (1.0, {6: _inverse1p}),
]


def mixed_model(X):
    y = np.zeros(len(X))
    for c, fs in MIXED_TERMS:
        t = np.full(len(X), c)
        for v, f in fs.items():
            t = t * f(X[:, v])
        y += t
    return y


def mixed_reference():
    """Mean, variance, first-order and total indices of ``mixed_model`` by 1-D quadrature."""
    from scipy import integrate

    laws = mixed_marginals()

    def one(x):
        return np.ones_like(x)

    @functools.lru_cache(None)
    def pair(v, i, j):
        fi = MIXED_TERMS[i][1].get(v, one) if i >= 0 else one
        fj = MIXED_TERMS[j][1].get(v, one) if j >= 0 else one
        lo, hi = laws[v].support()
        return integrate.quad(
            lambda x: fi(np.array(x)) * fj(np.array(x)) * laws[v].pdf(x),
            lo,
            hi,
            epsabs=1e-14,
            epsrel=1e-12,
            limit=200,
        )[0]

    T_ = range(len(MIXED_TERMS))
    mean = sum(MIXED_TERMS[i][0] * math.prod(pair(v, i, -1) for v in MIXED_TERMS[i][1]) for i in T_)

    def var(S):
        total = 0.0
        for i in T_:
            for j in T_:
                val = MIXED_TERMS[i][0] * MIXED_TERMS[j][0]
                for v in set(MIXED_TERMS[i][1]) | set(MIXED_TERMS[j][1]):
                    val *= pair(v, i, j) if v in S else pair(v, i, -1) * pair(v, j, -1)
                total += val
        return total - mean**2

    full = set(range(8))
    V = var(full)
    S = np.array([var({i}) for i in range(8)]) / V
    T = np.array([1.0 - var(full - {i}) / V for i in range(8)])
    return S, T


def mixed_design(n, seed):
    u = qmc.LatinHypercube(8, seed=seed).random(n)
    return np.column_stack([m.ppf(u[:, k]) for k, m in enumerate(mixed_marginals())])


def ours_mixed(X, Y):
    """Defaults from the marginals to the indices: Inputs, fit_pce, first_order, total."""
    inputs = Inputs(mixed_marginals())
    pce = fit_pce(None, inputs, samples=X, evaluations=Y)
    return pce.first_order(), pce.total()


def openturns_mixed(X, Y):
    """OpenTURNS' sparse chaos: its own polynomials per marginal, hyperbolic q = 0.5 up to
    total degree 10 (its ResourceMap defaults), LARS + corrected LOO."""
    import openturns as ot

    marg = [
        ot.TruncatedDistribution(ot.Gumbel(2.0, 10.0), 5.0, 25.0),
        ot.TruncatedDistribution(ot.Normal(30.0, 7.5), 0.0, ot.TruncatedDistribution.LOWER),
        ot.Uniform(0.0, 1.0),
        ot.Uniform(-1.0, 1.0),
        ot.Triangular(0.0, 0.3, 1.0),
        ot.Triangular(1.0, 2.4, 3.0),
        ot.Uniform(0.0, 2.0),
        ot.LogNormal(0.0, 0.25, 0.0),
    ]
    dist = ot.JointDistribution(marg)
    q = ot.ResourceMap.GetAsScalar("FunctionalChaosAlgorithm-QNorm")
    degree = ot.ResourceMap.GetAsUnsignedInteger("FunctionalChaosAlgorithm-MaximumTotalDegree")
    enum = ot.HyperbolicAnisotropicEnumerateFunction(8, q)
    factory = ot.OrthogonalProductPolynomialFactory(
        [ot.StandardDistributionPolynomialFactory(m) for m in marg], enum
    )
    size = enum.getBasisSizeFromTotalDegree(degree)
    select = ot.LeastSquaresMetaModelSelectionFactory(ot.LARS(), ot.CorrectedLeaveOneOut())
    algo = ot.FunctionalChaosAlgorithm(
        X,
        Y[:, None],
        dist,
        ot.FixedStrategy(factory, size),
        ot.LeastSquaresStrategy(X, Y[:, None], select),
    )
    algo.run()
    si = ot.FunctionalChaosSobolIndices(algo.getResult())
    S = np.array([si.getSobolIndex(i) for i in range(8)])
    T = np.array([si.getSobolTotalIndex(i) for i in range(8)])
    return S, T


def run_mixed(designs, budgets, have):
    S0, T0 = mixed_reference()
    ours_mixed(*(lambda X: (X, mixed_model(X)))(mixed_design(200, 99)))  # warm-up (numba)
    print(f"\n# eight mixed-law inputs, median over {designs} LHS designs (same for both)")
    print(
        f"{'N':>5} {'ecfm_uq err':>11} {'time s':>7} {'OpenTURNS err':>13} {'time s':>7} "
        f"{'err ratio':>9} {'time ratio':>10}"
    )
    out = []
    for n in budgets:
        rows = {"ours": [], "ot": []}
        for seed in range(designs):
            X = mixed_design(n, seed)
            Y = mixed_model(X)
            fits = [("ours", ours_mixed)] + ([("ot", openturns_mixed)] if have["openturns"] else [])
            for key, fn in fits:
                t = time.perf_counter()
                S, T = fn(X, Y)
                t = time.perf_counter() - t
                rows[key].append((max(np.abs(S - S0).max(), np.abs(T - T0).max()), t))
        eo, to = np.median(rows["ours"], axis=0)
        if rows["ot"]:
            ep, tp = np.median(rows["ot"], axis=0)
            print(
                f"{n:5d} {eo:11.1e} {to:7.2f} {ep:13.1e} {tp:7.2f} {eo / ep:9.2f} {to / tp:10.2f}"
            )
        else:
            print(f"{n:5d} {eo:11.1e} {to:7.2f}")
        out.append((n, rows))
    return out


def run_sampling(seeds=10):
    """The 20-input g-function by ``ecfm_uq.mc.sobol_indices`` at n = 2^13."""
    from ecfm_uq.mc import sobol_indices

    a = np.array([0, 1, 4.5, 9] + [99] * 16, dtype=float)
    Vi = 1.0 / (3.0 * (1.0 + a) ** 2)
    V = np.prod(1.0 + Vi) - 1.0
    S0 = Vi / V
    T0 = np.array([Vi[i] * np.prod(np.delete(1.0 + Vi, i)) for i in range(20)]) / V

    def g(X):
        return np.prod((np.abs(4.0 * X - 2.0) + a) / (1.0 + a), axis=-1)

    errs, inside, times = [], [], []
    for seed in range(seeds):
        t = time.perf_counter()
        r = sobol_indices(g, [(0.0, 1.0)] * 20, 2**13, seed=seed, vectorized=True)
        times.append(time.perf_counter() - t)
        errs.append(max(np.abs(r.first_order - S0).max(), np.abs(r.total - T0).max()))
        inside += list((r.first_order_interval[0] <= S0) & (S0 <= r.first_order_interval[1]))
        inside += list((r.total_interval[0] <= T0) & (T0 <= r.total_interval[1]))
    print(
        f"\n# 20-input g-function, sobol_indices(n=2^13, {r.n_evaluations} runs), {seeds} seeds: "
        f"largest index error {max(errs):.3f} (median {np.median(errs):.4f}), truth inside "
        f"{np.mean(inside):.1%} of the 95 % intervals, {np.median(times):.2f} s per call"
    )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", type=int, default=3, help="LHS designs per budget")
    parser.add_argument("--quick", action="store_true", help="budgets 100 and 500 only")
    parser.add_argument(
        "--part",
        choices=("all", "analytic", "mixed", "sampling"),
        default="all",
        help="the four analytic problems, the eight mixed-law inputs at N = 100, 300, 1000, "
        "or the g-function by sampling",
    )
    args = parser.parse_args(argv)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass
    have = {m: available(m) for m in ("chaospy", "openturns", "sklearn")}
    for m, ok in have.items():
        if not ok:
            print(f"{m}: not installed (its rows are skipped)")
    if args.part in ("all", "mixed"):
        run_mixed(args.designs, (100, 300) if args.quick else (100, 300, 1000), have)
    if args.part in ("all", "sampling"):
        run_sampling()
    if args.part not in ("all", "analytic"):
        return
    warm_up(have)
    budgets = BUDGETS[:2] if args.quick else BUDGETS
    t0 = time.perf_counter()
    rows = []
    for problem in (Ishigami(), SobolG(), ShortColumn(), GammaBetaLognormal()):
        rows += run_problem(problem, args.designs, budgets, have)

    print(
        f"median over {args.designs} LHS designs for regression; single thread; "
        "index error = max |first-order or total - analytic|"
    )
    header = f"{'problem':11} {'budget':>6} {'method':22} {'runs':>5} {'mean err':>9} {'var err':>9} {'index err':>9} {'time s':>8}"
    print(header)
    print("-" * len(header))
    for prob, n, name, runs, em, ev, ei, dt in rows:
        e = " ".join(f"{v:9.1e}" if np.isfinite(v) else f"{'fail':>9}" for v in (em, ev, ei))
        print(f"{prob:11} {n:6d} {name:22} {runs:5d} {e} {dt:8.3f}")

    print()
    for prob in ("ishigami", "sobol-g", "short-col", "gam-beta-ln"):
        for n in budgets:
            sel = [r for r in rows if r[0] == prob and r[1] == n]
            ours = [r for r in sel if r[2].startswith("ours")]
            peers = [r for r in sel if not r[2].startswith("ours")]
            if not peers:
                continue
            key = lambda r: r[6] if np.isfinite(r[6]) else np.inf
            best_o = min(ours, key=key)
            best_p = min(peers, key=key)
            fast_o = min(ours, key=lambda r: r[7])
            fast_p = min(peers, key=lambda r: r[7])
            print(
                f"{prob} n={n}: index error ours {best_o[6]:.1e} ({best_o[2]}, {best_o[7]:.3f} s) "
                f"vs best peer {best_p[6]:.1e} ({best_p[2]}, {best_p[7]:.3f} s): "
                f"error ratio {best_o[6] / best_p[6]:.2g}, time ratio {best_o[7] / best_p[7]:.2g}; "
                f"fastest ours {fast_o[7]:.3f} s ({fast_o[2]}, {fast_o[6]:.1e}) vs fastest peer "
                f"{fast_p[7]:.3f} s ({fast_p[2]}, {fast_p[6]:.1e})"
            )
    if have["chaospy"]:
        t_sens = chaospy_own_indices_time(Ishigami(), 4)
        print(f"chaospy Sens_m + Sens_t at order 4 (Ishigami): {t_sens:.2f} s")
    print(f"total benchmark time: {time.perf_counter() - t0:.0f} s")

    ish = [r for r in rows if r[0] == "ishigami" and r[1] == 500]
    ours = min(r[6] for r in ish if r[2].startswith("ours"))
    peers = [r[6] for r in ish if not r[2].startswith("ours")]
    theirs = f"{min(peers):.1e}" if peers else "n/a (no peer installed)"
    print(
        f"pce_peers: ishigami max index error {ours:.1e} vs best peer {theirs} at 500 evaluations"
    )


if __name__ == "__main__":
    main()
