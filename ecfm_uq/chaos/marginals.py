"""One input variable's law and its map to a germ (Askey-Wiener or isoprobabilistic).

A marginal that belongs to the Askey scheme is an affine image of its germ, so the chaos
basis is polynomial in the input itself:

==========================  =============================  ==========================
input                       germ                           map
==========================  =============================  ==========================
uniform U(a, b)             U(0, 1), Legendre              x = a + (b - a) omega
normal N(mu, sigma)         N(0, 1), Hermite               x = mu + sigma xi
gamma (k, loc, scale)       Gamma(k), Laguerre             x = loc + scale omega
beta (a, b, loc, scale)     Beta(a, b), Jacobi             x = loc + scale omega
==========================  =============================  ==========================

Any other continuous marginal is reached through an isoprobabilistic transform
(Rosenblatt / Nataf): a lognormal is :math:`x = loc + scale\\,e^{s\\xi}` with a Hermite
germ, a bounded law (truncated normal, ...) is :math:`x = F^{-1}(\\omega)` with a uniform
germ, any other (Weibull, Gumbel, ...) is :math:`x = F^{-1}(\\Phi(\\xi))` with a Hermite
germ, evaluated through the survival function in the upper tail so no precision is lost
there. Under a Gaussian copula every marginal is instead reached from a correlated
standard normal :math:`z` (:meth:`Marginal.from_normal`).
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy import special, stats

from .germs import Germ

__all__ = ["Marginal", "as_marginal"]

_HERMITE = Germ("hermite")
_LEGENDRE = Germ("legendre")


def _norm_cdf_pair(z):
    """(Phi(z), Phi(-z)) without cancellation."""
    return special.ndtr(z), special.ndtr(-z)


def _ppf_from_normal(law, z):
    """F^{-1}(Phi(z)), through the survival function for z > 0 (no loss in the upper tail)."""
    lo, hi = _norm_cdf_pair(z)
    with np.errstate(invalid="ignore"):
        return np.where(z <= 0, law.ppf(lo), law.isf(hi))


def _normal_from_cdf(law, x):
    """Phi^{-1}(F(x)), through the survival function where F(x) > 1/2."""
    c, s = law.cdf(x), law.sf(x)
    with np.errstate(divide="ignore"):
        return np.where(c <= 0.5, special.ndtri(c), -special.ndtri(s))


class Marginal:
    """One input's law, the germ it is expanded on, and the maps between them.

    Build it with :func:`as_marginal` from a scipy.stats frozen distribution or a chaospy
    distribution.

    Attributes
    ----------
    kind : {"uniform", "normal", "gamma", "beta", "lognormal", "bounded", "unbounded"}
        The first four are Askey-Wiener (affine in the germ); the others are transforms.
    germ : Germ
        The germ of the independent expansion.
    law : scipy.stats frozen distribution
        The same law, for CDF, quantiles and sampling.
    loc, scale : float
        The affine map ``x = loc + scale * germ`` (Askey kinds; lognormal: ``x = loc +
        scale * exp(s * xi)``).
    params : tuple
        Shape parameters (gamma k; beta a, b; lognormal s).
    affine : bool
        The input is an affine image of its germ (a PCE is then a polynomial in it).
    """

    def __init__(self, kind, law, loc=0.0, scale=1.0, params=(), label=None):
        self.kind = kind
        self.law = law
        self.loc = float(loc)
        self.scale = float(scale)
        self.params = tuple(float(p) for p in params)
        if kind == "uniform" or kind == "bounded":
            self.germ = _LEGENDRE
        elif kind == "gamma":
            self.germ = Germ("laguerre", shape=self.params[0])
        elif kind == "beta":
            self.germ = Germ("jacobi", a=self.params[0], b=self.params[1])
        else:
            self.germ = _HERMITE
        self.affine = kind in ("uniform", "normal", "gamma", "beta")
        self.label = label or kind

    def __repr__(self):
        return self.label

    def __eq__(self, other):
        if not isinstance(other, Marginal):
            return NotImplemented
        return (self.kind, self.loc, self.scale, self.params, self.label) == (
            other.kind,
            other.loc,
            other.scale,
            other.params,
            other.label,
        )

    __hash__ = None

    @property
    def finite_variance(self):
        """The law has a finite variance (False for Cauchy, Student t with 2 dof, ...)."""
        if self.affine or self.kind == "lognormal":
            return True
        try:
            v = float(self.law.var())
        except Exception:  # a law without a variance method: assume finite
            return True
        return bool(np.isfinite(v))

    @property
    def support(self):
        return tuple(float(v) for v in self.law.support())

    # -- the independent expansion: x <-> its own germ -------------------------------
    def from_germ(self, g):
        """Input values of germ values ``g`` (an array)."""
        if self.affine:
            return self.loc + self.scale * g
        if self.kind == "lognormal":
            return self.loc + self.scale * np.exp(self.params[0] * g)
        if self.kind == "bounded":
            return self.law.ppf(g)
        return _ppf_from_normal(self.law, g)

    def to_germ(self, x):
        """Germ values of input values ``x`` (inside the support)."""
        if self.affine:
            return (x - self.loc) / self.scale
        if self.kind == "lognormal":
            return np.log((x - self.loc) / self.scale) / self.params[0]
        if self.kind == "bounded":
            return self.law.cdf(x)
        return _normal_from_cdf(self.law, x)

    # -- the Gaussian copula: x <-> a standard normal z ------------------------------
    def from_normal(self, z):
        """Input values of standard normal values ``z`` (Nataf: x = F^{-1}(Phi(z)))."""
        if self.kind == "normal":
            return self.loc + self.scale * z
        if self.kind == "lognormal":
            return self.loc + self.scale * np.exp(self.params[0] * z)
        return _ppf_from_normal(self.law, z)

    def to_normal(self, x):
        """Standard normal values of input values ``x`` (z = Phi^{-1}(F(x)))."""
        if self.kind == "normal":
            return (x - self.loc) / self.scale
        if self.kind == "lognormal":
            return np.log((x - self.loc) / self.scale) / self.params[0]
        return _normal_from_cdf(self.law, x)

    def to_chaospy(self):
        """The law as a chaospy distribution (Askey kinds and lognormal)."""
        import chaospy

        if self.kind == "uniform":
            return chaospy.Uniform(self.loc, self.loc + self.scale)
        if self.kind == "normal":
            return chaospy.Normal(self.loc, self.scale)
        if self.kind == "gamma":
            return chaospy.Gamma(self.params[0], self.scale, self.loc)
        if self.kind == "beta":
            return chaospy.Beta(*self.params, lower=self.loc, upper=self.loc + self.scale)
        if self.kind == "lognormal":
            return chaospy.LogNormal(np.log(self.scale), self.params[0], shift=self.loc)
        raise ValueError(f"no chaospy equivalent is known for the input law {self.label}")


# --------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------
def _scipy_params(frozen):
    """Shape parameters, loc and scale of a frozen scipy.stats distribution."""
    shapes = [s.strip() for s in (frozen.dist.shapes or "").split(",") if s.strip()]
    names = [*shapes, "loc", "scale"]
    vals = dict(zip(names, frozen.args, strict=False))
    vals.update(frozen.kwds)
    return (
        [float(vals[s]) for s in shapes],
        float(vals.get("loc", 0.0)),
        float(vals.get("scale", 1.0)),
    )


def _from_scipy(d, name):
    if isinstance(d.dist, stats.rv_discrete):
        raise TypeError(
            f"input {name!r} is the discrete distribution {d.dist.name}: a polynomial chaos "
            "needs continuous inputs; treat the input as continuous or condition on its values"
        )
    shapes, loc, scale = _scipy_params(d)
    if not (np.isfinite(loc) and np.isfinite(scale) and scale > 0) or not np.all(
        np.isfinite(shapes)
    ):
        raise ValueError(
            f"input {name!r} has invalid parameters loc={loc}, scale={scale}, {shapes}"
        )
    kind = d.dist.name
    if kind == "uniform":
        return Marginal("uniform", d, loc, scale, label=f"U({loc:g}, {loc + scale:g})")
    if kind == "norm":
        return Marginal("normal", d, loc, scale, label=f"N({loc:g}, {scale:g})")
    if kind in ("gamma", "expon"):
        k = shapes[0] if kind == "gamma" else 1.0
        return Marginal(
            "gamma", d, loc, scale, (k,), label=f"Gamma({k:g}, loc={loc:g}, scale={scale:g})"
        )
    if kind == "beta":
        return Marginal(
            "beta",
            d,
            loc,
            scale,
            shapes,
            label=f"Beta({shapes[0]:g}, {shapes[1]:g}, loc={loc:g}, scale={scale:g})",
        )
    if kind == "lognorm":
        return Marginal(
            "lognormal",
            d,
            loc,
            scale,
            shapes,
            label=f"LogNormal(s={shapes[0]:g}, loc={loc:g}, scale={scale:g})",
        )
    lo, hi = d.support()
    bounded = np.isfinite(lo) and np.isfinite(hi)
    return Marginal("bounded" if bounded else "unbounded", d, label=f"{kind}{tuple(shapes)}")


def _cp_param(d, key, fallback, inner=False):
    """A chaospy parameter read exactly where this chaospy version exposes it, else moments."""
    try:
        params = d._dist._parameters if inner else d._parameters
        return float(np.asarray(params[key]).ravel()[0])
    except Exception:  # chaospy internals differ between versions: use the moments
        return float(fallback())


def _from_chaospy(d, name):
    import chaospy

    if len(d) != 1:
        raise ValueError(
            f"input {name!r} is a {len(d)}-variate chaospy distribution; pass it as `inputs`"
        )
    if getattr(d, "interpret_as_integer", False):
        raise TypeError(
            f"input {name!r} is the discrete distribution {type(d).__name__}: a polynomial "
            "chaos needs continuous inputs; treat the input as continuous or condition on its values"
        )
    lower, upper = float(d.lower[0]), float(d.upper[0])
    m1 = float(d.mom(1))
    var = float(d.mom(2)) - m1**2
    cls = type(d).__name__
    if isinstance(d, chaospy.Uniform):
        return _from_scipy(stats.uniform(lower, upper - lower), name)
    if cls == "Normal":
        mu = _cp_param(d, "shift", lambda: m1)
        sigma = _cp_param(d, "scale", lambda: np.sqrt(var))
        return _from_scipy(stats.norm(mu, sigma), name)
    if cls in ("Gamma", "Exponential"):
        shift = _cp_param(d, "shift", lambda: lower)
        k = (
            1.0
            if cls == "Exponential"
            else _cp_param(d, "a", lambda: (m1 - shift) ** 2 / var, True)
        )
        scale = _cp_param(d, "scale", lambda: var / (m1 - shift))
        return _from_scipy(stats.gamma(k, shift, scale), name)
    if cls == "Beta":
        u = (m1 - lower) / (upper - lower)
        v = var / (upper - lower) ** 2
        common = u * (1 - u) / v - 1
        a = _cp_param(d, "a", lambda: u * common, True)
        b = _cp_param(d, "b", lambda: (1 - u) * common, True)
        return _from_scipy(stats.beta(a, b, lower, upper - lower), name)
    if cls == "LogNormal":
        shift = _cp_param(d, "shift", lambda: lower)
        a1, a2 = m1 - shift, float(d.mom(2)) - 2 * shift * m1 + shift**2
        s2 = np.log(a2 / a1**2)
        mu = np.log(a1) - 0.5 * s2
        return _from_scipy(stats.lognorm(np.sqrt(s2), shift, np.exp(mu)), name)
    # any other continuous chaospy law: through its own CDF and inverse CDF
    return Marginal("unbounded", _ChaospyLaw(d), label=cls)


class _ChaospyLaw:
    """A 1-D chaospy distribution with the scipy frozen-distribution methods used here."""

    def __init__(self, d):
        self.d = d

    def cdf(self, x):
        return np.asarray(self.d.fwd(np.asarray(x, dtype=float)), dtype=float)

    def sf(self, x):
        return 1.0 - self.cdf(x)

    def ppf(self, u):
        return np.asarray(self.d.inv(np.asarray(u, dtype=float)), dtype=float)

    def isf(self, u):
        return self.ppf(1.0 - np.asarray(u, dtype=float))

    def support(self):
        return (-np.inf, np.inf)

    def var(self):
        return float(self.d.mom(2)) - float(self.d.mom(1)) ** 2


def as_marginal(dist, name="x"):
    """A :class:`Marginal` from a scipy.stats frozen distribution or a 1-D chaospy one.

    Raises
    ------
    TypeError
        A discrete distribution, or an object that is neither (naming the input).
    """
    if isinstance(dist, Marginal):
        return dist
    if hasattr(dist, "dist") and isinstance(
        getattr(dist, "dist", None), stats.rv_continuous | stats.rv_discrete
    ):
        return _from_scipy(dist, name)
    if type(dist).__module__.startswith("chaospy"):
        return _from_chaospy(dist, name)
    if isinstance(dist, numbers.Number):
        raise TypeError(
            f"input {name!r} is the number {dist!r}: pass a distribution (a constant is not an input)"
        )
    raise TypeError(
        f"input {name!r} must be a scipy.stats frozen distribution (e.g. scipy.stats.norm(0, 1)) "
        f"or a chaospy distribution, got {type(dist).__name__}"
    )
