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

import functools
import numbers
import re

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

    @property
    def own_by_default(self):
        """Expand on the law's own polynomials unless asked otherwise (see ``Inputs``)?

        Laws of bounded support and truncated normals: their moments determine them, so
        their own polynomials are dense in L2; an Askey law keeps its germ, and other
        unbounded laws (lognormal: not determined by its moments) the transform.
        """
        if self.kind == "bounded":
            return True
        name = getattr(getattr(self.law, "dist", None), "name", None)
        if name == "truncnorm":
            return True
        inner = getattr(self.law, "d", None)
        return type(inner).__name__ == "TruncatedDistribution" and repr(inner).startswith(
            "truncate(Normal("
        )

    def own(self, name="x"):
        """This law expanded on its own orthonormal polynomials (arbitrary chaos).

        The germ becomes the standardised input :math:`g = (x - \\mu)/\\sigma` with the
        polynomials of the law itself (:class:`~ecfm_uq.chaos.ownlaw.OwnGerm`), so a model
        polynomial in the input is represented exactly; ``kind`` is kept.
        """
        from .ownlaw import OwnGerm

        if self.germ.family == "own":
            return self
        out = Marginal.__new__(Marginal)
        out.__dict__.update(self.__dict__)
        germ = OwnGerm(self.law, name=name, label=self.label)
        out.germ = germ
        out.loc, out.scale = germ.mean, germ.std
        out.affine = True
        out.label = f"{self.label} (own polynomials)"
        return out

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

    @functools.cached_property
    def finite_variance(self):
        """The law has a finite variance (False for Cauchy, Student t with 2 dof, ...).

        Computed once per marginal: for a law without closed-form moments (a custom
        ``rv_continuous``) scipy integrates numerically, which takes up to seconds.
        """
        if self.affine or self.kind in ("lognormal", "bounded"):
            return True  # closed-form moments, or a bounded support
        try:
            v = float(self.law.var())
        except Exception:  # a law without a variance method: assume finite
            return True
        return bool(np.isfinite(v))

    @functools.cached_property
    def finite_mean(self):
        """The law has a finite mean (False for Cauchy, Pareto with shape <= 1, ...)."""
        if self.affine or self.kind in ("lognormal", "bounded"):
            return True
        try:
            with np.errstate(all="ignore"):
                m = float(self.law.mean())
        except Exception:  # a law without a mean method: assume finite
            return True
        return bool(np.isfinite(m))

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
        raise _discrete(name, d.dist.name)
    _check_normalized(d, name)
    shapes, loc, scale = _scipy_params(d)
    # shape parameters may be infinite (truncnorm(a, np.inf): a normal truncated below);
    # scipy itself decides whether they are valid, seen as a finite median
    with np.errstate(all="ignore"):
        median = float(np.asarray(d.ppf(0.5)))
    if (
        not (np.isfinite(loc) and np.isfinite(scale) and scale > 0)
        or np.any(np.isnan(shapes))
        or not np.isfinite(median)
    ):
        raise ValueError(
            f"input {name!r} ({d.dist.name}) has parameters scipy rejects: loc={loc}, "
            f"scale={scale}, shapes={shapes} (its median is {median}); check them against "
            f"scipy.stats.{d.dist.name}'s documentation"
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
    return _transformed(d, f"{kind}{tuple(shapes)}")


def _transformed(law, label):
    """A marginal reached through its CDF: uniform germ when bounded, normal germ else."""
    lo, hi = (float(v) for v in law.support())
    bounded = np.isfinite(lo) and np.isfinite(hi)
    return Marginal("bounded" if bounded else "unbounded", law, label=label)


# scipy >= 1.15: the new-style distribution classes (stats.Normal, stats.truncate(...),
# stats.make_distribution(...)); looked up by name so older scipy versions still import
def _new_style_classes():
    try:
        from scipy.stats import _distribution_infrastructure as infra
    except ImportError:  # pragma: no cover - scipy < 1.15
        return (), ()
    return (
        getattr(infra, "ContinuousDistribution", ()),
        getattr(infra, "DiscreteDistribution", ()),
    )


class _NewStyleLaw:
    """A scipy new-style continuous distribution with the frozen-distribution methods used here.

    ``cdf``/``sf``/``ppf``/``isf`` map to scipy's ``cdf``/``ccdf``/``icdf``/``iccdf``
    (the complementary ones keep the upper tail's precision); the variance is read once.
    """

    def __init__(self, d):
        self.d = d

    def cdf(self, x):
        return np.asarray(self.d.cdf(np.asarray(x, dtype=float)), dtype=float)

    def sf(self, x):
        return np.asarray(self.d.ccdf(np.asarray(x, dtype=float)), dtype=float)

    def ppf(self, u):
        return np.asarray(self.d.icdf(np.asarray(u, dtype=float)), dtype=float)

    def isf(self, u):
        return np.asarray(self.d.iccdf(np.asarray(u, dtype=float)), dtype=float)

    def pdf(self, x):
        return np.asarray(self.d.pdf(np.asarray(x, dtype=float)), dtype=float)

    def support(self):
        lo, hi = self.d.support()
        return float(lo), float(hi)

    def var(self):
        return float(self.d.variance())

    def mean(self):
        return float(self.d.mean())


def _from_new_style(d, name):
    cls = type(d).__name__
    lo, hi = (float(np.asarray(v)) for v in d.support())
    if type(d).__name__ == "Normal" and type(d).__module__.startswith("scipy.stats"):
        return _from_scipy(stats.norm(float(d.mean()), float(d.standard_deviation())), name)
    if type(d).__name__ == "Uniform" and type(d).__module__.startswith("scipy.stats"):
        return _from_scipy(stats.uniform(lo, hi - lo), name)
    label = re.sub(r"np\.float64\(([^)]*)\)", r"\1", repr(d))  # scipy's own repr, cleaned
    return _transformed(_NewStyleLaw(d), label if len(label) <= 80 else cls)


class _DuckLaw:
    """Any object with ``cdf`` and ``ppf`` (and optionally ``sf``, ``isf``, ``support``)."""

    def __init__(self, d):
        self.d = d

    def cdf(self, x):
        return np.asarray(self.d.cdf(np.asarray(x, dtype=float)), dtype=float)

    def sf(self, x):
        if hasattr(self.d, "sf"):
            return np.asarray(self.d.sf(np.asarray(x, dtype=float)), dtype=float)
        return 1.0 - self.cdf(x)

    def ppf(self, u):
        return np.asarray(self.d.ppf(np.asarray(u, dtype=float)), dtype=float)

    def isf(self, u):
        if hasattr(self.d, "isf"):
            return np.asarray(self.d.isf(np.asarray(u, dtype=float)), dtype=float)
        return self.ppf(1.0 - np.asarray(u, dtype=float))

    def support(self):
        if hasattr(self.d, "support"):
            lo, hi = self.d.support()
            return float(lo), float(hi)
        return float(self.ppf(0.0)), float(self.ppf(1.0))

    def var(self):
        return float(self.d.var())


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
    """A :class:`Marginal` from any continuous 1-D law.

    Accepted: a scipy.stats frozen distribution (truncated ones with an infinite bound
    included, e.g. ``truncnorm(a, np.inf, loc, scale)``), an instance of a user's
    ``rv_continuous`` subclass (frozen or, without shape parameters, not), a scipy
    new-style distribution (``stats.Normal(mu=, sigma=)``, ``stats.truncate(...)``,
    ``stats.make_distribution(...)``), a 1-D chaospy distribution, or any object with
    ``cdf`` and ``ppf`` methods (and optionally ``sf``, ``isf``, ``support``, ``var``).

    Raises
    ------
    TypeError
        A discrete distribution, or an object that is neither (naming the input).
    """
    if isinstance(dist, Marginal):
        return dist
    if isinstance(dist, type):
        raise TypeError(
            f"input {name!r} is the class {dist.__name__}, not a law: pass an instance, e.g. "
            f"{dist.__name__}(a=..., b=...) for an rv_continuous subclass, or a frozen scipy "
            "law such as scipy.stats.norm(0, 1)"
        )
    if hasattr(dist, "dist") and isinstance(
        getattr(dist, "dist", None), stats.rv_continuous | stats.rv_discrete
    ):
        return _from_scipy(dist, name)
    if isinstance(dist, stats.rv_discrete):
        raise _discrete(name, dist.name)
    if isinstance(dist, stats.rv_continuous):
        # an unfrozen law (e.g. an instance of a user's rv_continuous subclass)
        if dist.numargs:
            raise TypeError(
                f"input {name!r} is the scipy law {dist.name} without its shape parameters "
                f"({dist.shapes}); freeze it: {dist.name}({dist.shapes}, loc=..., scale=...)"
            )
        return _from_scipy(dist(), name)
    continuous, discrete = _new_style_classes()
    if discrete and isinstance(dist, discrete):
        raise _discrete(name, type(dist).__name__)
    if continuous and isinstance(dist, continuous):
        return _from_new_style(dist, name)
    if type(dist).__module__.startswith("chaospy"):
        return _from_chaospy(dist, name)
    if isinstance(dist, numbers.Number):
        raise TypeError(
            f"input {name!r} is the number {dist!r}: pass a distribution (a constant is not an input)"
        )
    if hasattr(dist, "cdf") or hasattr(dist, "ppf"):
        missing = [m for m in ("cdf", "ppf") if not callable(getattr(dist, m, None))]
        if missing:
            raise TypeError(
                f"input {name!r} ({type(dist).__name__}) has no {' and no '.join(missing)}: "
                "a chaos input is mapped to its germ through its CDF and inverse CDF (ppf); "
                "give the law both methods, or pass a scipy.stats distribution"
            )
        return _transformed(_DuckLaw(dist), type(dist).__name__)
    raise TypeError(
        f"input {name!r} must be a scipy.stats frozen distribution (e.g. scipy.stats.norm(0, "
        "1)) or a new-style one (scipy.stats.Normal(mu=0, sigma=1)), a chaospy distribution "
        f"or an object with cdf and ppf methods, got {type(dist).__name__}"
    )


#: how far from 1 the integral of a user's density may be
DENSITY_TOL = 1e-6


def _check_normalized(d, name):
    """A user's ``rv_continuous`` subclass with its own ``_pdf``: the density must
    integrate to 1 (within ``DENSITY_TOL``) over its support, else every moment, quantile
    and expansion of it is off by the factor (scipy does not check)."""
    law = d.dist
    if type(law).__module__.startswith("scipy.") or type(law)._pdf is stats.rv_continuous._pdf:
        return
    from scipy import integrate

    lo, hi = (float(v) for v in d.support())
    with np.errstate(all="ignore"):
        total, err = integrate.quad(lambda x: float(d.pdf(x)), lo, hi, limit=200)
    if not np.isfinite(total) or abs(total - 1.0) > DENSITY_TOL:
        raise ValueError(
            f"input {name!r} ({type(law).__name__}): its density integrates to {total:.8g} over "
            f"[{lo:g}, {hi:g}], not 1: divide _pdf by {total:.8g} (or fix its support a=, b=)"
        )


def _discrete(name, law):
    return TypeError(
        f"input {name!r} is the discrete distribution {law}: a polynomial chaos needs "
        "continuous inputs; treat the input as continuous or condition on its values"
    )
