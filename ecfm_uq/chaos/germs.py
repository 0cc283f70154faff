"""The germs of the Askey scheme: one random variable and its orthogonal polynomials.

A chaos basis is a product of univariate orthonormal polynomials, one family per germ
variable, each orthogonal for that variable's density (Xiu & Karniadakis 2002):

=========  ===========================  ===============================================
family     germ                         polynomials (orthonormal)
=========  ===========================  ===============================================
legendre   U(0, 1) (the paper's germ)   shifted Legendre :math:`\\sqrt{2n+1}P_n(2\\omega-1)`
hermite    N(0, 1)                      probabilists' Hermite :math:`He_n/\\sqrt{n!}`
laguerre   Gamma(shape k, scale 1)      generalised Laguerre :math:`L_n^{(k-1)}`, normed
jacobi     Beta(a, b) on [0, 1]         Jacobi :math:`P_n^{(b-1, a-1)}(2\\omega - 1)`, normed
=========  ===========================  ===============================================

Every family is described by the monic three-term recurrence of its probability measure,

.. math:: \\pi_{n+1}(x) = (x - a_n)\\,\\pi_n(x) - b_n\\,\\pi_{n-1}(x),

from which the orthonormal values, the Gauss rule (scipy's, normalised to probability
weights) and the exact triple products follow. Legendre keeps its own closed-form kernels
(bit-identical to the uniform-only code); Hermite triple products have the closed form
:math:`\\mathbb E[He_iHe_jHe_k] = i!j!k!/((s-i)!(s-j)!(s-k)!)`; Laguerre and Jacobi
triple products are read off the Jacobi matrix (exact algebra, no quadrature).
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy import stats

from ._kernels import hermite_triple_1d, legendre_table, orthonormal_table, recurrence_triple_1d
from ._kernels import triple_1d as legendre_triple_1d
from .quadrature import gauss_hermite, gauss_jacobi, gauss_laguerre, gauss_legendre

__all__ = ["FAMILIES", "Germ", "as_germs"]

FAMILIES = ("legendre", "hermite", "laguerre", "jacobi")


def _positive(name, value):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"`{name}` must be a positive number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"`{name}` must be a positive finite number, got {value!r}")
    return value


class Germ:
    """One germ variable of the Askey scheme and its orthonormal polynomial family.

    Parameters
    ----------
    family : {"legendre", "hermite", "laguerre", "jacobi"}
    shape : float, optional
        ``"laguerre"`` only: the gamma shape :math:`k > 0` (density
        :math:`\\omega^{k-1}e^{-\\omega}/\\Gamma(k)`). Default 1 (exponential).
    a, b : float, optional
        ``"jacobi"`` only: the beta parameters (density
        :math:`\\omega^{a-1}(1-\\omega)^{b-1}/B(a, b)` on [0, 1]). ``a = b = 1`` is the
        uniform germ, but written as ``"legendre"`` it uses the closed-form kernels.

    Attributes
    ----------
    family : str
    params : tuple of float
    symmetric : bool
        The density is symmetric about its mean, so odd triple products vanish (the parity
        selection rule).
    support : (float, float)

    Examples
    --------
    >>> Germ("hermite").gauss(3)[0].round(6).tolist()
    [-1.732051, 0.0, 1.732051]
    """

    def __init__(self, family="legendre", *, shape=None, a=None, b=None):
        if not isinstance(family, str) or family not in FAMILIES:
            raise ValueError(f"`germ` must be one of {list(FAMILIES)}, got {family!r}")
        self.family = family
        if family == "laguerre":
            self.params = (_positive("shape", 1.0 if shape is None else shape),)
        elif family == "jacobi":
            if a is None or b is None:
                raise TypeError("a 'jacobi' germ needs its beta parameters: Germ('jacobi', a=, b=)")
            self.params = (_positive("a", a), _positive("b", b))
        else:
            self.params = ()
        if (shape is not None and family != "laguerre") or (
            (a is not None or b is not None) and family != "jacobi"
        ):
            raise TypeError(f"a {family!r} germ takes no parameters `shape`, `a`, `b` of others")
        self.symmetric = family in ("legendre", "hermite") or (
            family == "jacobi" and self.params[0] == self.params[1]
        )
        self.support = {
            "legendre": (0.0, 1.0),
            "hermite": (-np.inf, np.inf),
            "laguerre": (0.0, np.inf),
            "jacobi": (0.0, 1.0),
        }[family]

    # -- identity ----------------------------------------------------------------------
    def __repr__(self):
        if self.family == "laguerre":
            return f"Germ('laguerre', shape={self.params[0]:g})"
        if self.family == "jacobi":
            return f"Germ('jacobi', a={self.params[0]:g}, b={self.params[1]:g})"
        return f"Germ({self.family!r})"

    def __eq__(self, other):
        if not isinstance(other, Germ):
            return NotImplemented
        return (self.family, self.params) == (other.family, other.params)

    def __hash__(self):
        return hash((self.family, self.params))

    @property
    def distribution(self):
        """The germ's law as a frozen ``scipy.stats`` distribution."""
        if self.family == "legendre":
            return stats.uniform()
        if self.family == "hermite":
            return stats.norm()
        if self.family == "laguerre":
            return stats.gamma(self.params[0])
        return stats.beta(*self.params)

    def to_chaospy(self):
        """The germ's law as a chaospy distribution."""
        import chaospy

        if self.family == "legendre":
            return chaospy.Uniform(0, 1)
        if self.family == "hermite":
            return chaospy.Normal(0, 1)
        if self.family == "laguerre":
            return chaospy.Gamma(self.params[0])
        return chaospy.Beta(*self.params)

    # -- recurrence, values, rules -----------------------------------------------------
    def recurrence(self, n):
        """Monic recurrence coefficients :math:`a_0..a_{n-1}`, :math:`b_0..b_{n-1}` (``b_0 = 1``).

        Hermite: :math:`a_m = 0, b_m = m`. Laguerre (shape k): :math:`a_m = 2m + k`,
        :math:`b_m = m(m + k - 1)`. Jacobi on [0, 1] with :math:`\\alpha = b - 1`,
        :math:`\\beta = a - 1`: the classical [-1, 1] coefficients mapped by
        :math:`\\omega = (t + 1)/2` (:math:`a \\to (a + 1)/2`, :math:`b \\to b/4`).
        """
        m = np.arange(n, dtype=float)
        if self.family == "hermite":
            a, b = np.zeros(n), m.copy()
        elif self.family == "laguerre":
            k = self.params[0]
            a, b = 2.0 * m + k, m * (m + k - 1.0)
        else:
            pa, pb = self.params if self.family == "jacobi" else (1.0, 1.0)
            al, be = pb - 1.0, pa - 1.0
            s = 2.0 * m + al + be
            with np.errstate(divide="ignore", invalid="ignore"):
                at = (be**2 - al**2) / (s * (s + 2.0))
                bt = 4.0 * m * (m + al) * (m + be) * (m + al + be) / (s**2 * (s + 1.0) * (s - 1.0))
            if n > 0:
                at[0] = (be - al) / (al + be + 2.0)
            if n > 1:
                bt[1] = 4.0 * (1.0 + al) * (1.0 + be) / ((2.0 + al + be) ** 2 * (3.0 + al + be))
            a, b = 0.5 * (at + 1.0), 0.25 * bt
        if n > 0:
            b[0] = 1.0
        return a, b

    def table(self, x, p):
        """Orthonormal values ``V[q, m]`` = :math:`\\psi_m(x_q)`, shape (n, p + 1)."""
        x = np.ascontiguousarray(x, dtype=float)
        if self.family == "legendre":
            return legendre_table(x, p)
        a, b = self.recurrence(p + 1)
        return orthonormal_table(x, p, a, np.sqrt(b))

    def gauss(self, n):
        """n-point Gauss rule of the germ: nodes and probability weights (summing to 1).

        Exact for polynomials of degree :math:`\\le 2n - 1`.
        """
        if self.family == "legendre":
            return gauss_legendre(n)
        if self.family == "hermite":
            return gauss_hermite(n)
        if self.family == "laguerre":
            return gauss_laguerre(n, self.params[0])
        return gauss_jacobi(n, *self.params)

    def triple(self, p, normalized=True):
        """Exact table :math:`t_{ijk} = \\mathbb E[\\psi_i\\psi_j\\psi_k]`, ``i, j, k <= p``."""
        if self.family == "legendre":
            return legendre_triple_1d(p, bool(normalized))
        if not normalized:
            raise ValueError(f"only the Legendre germ has an unnormalised basis, not {self!r}")
        if self.family == "hermite":
            return hermite_triple_1d(p)
        a, b = self.recurrence(2 * p + 2)
        return recurrence_triple_1d(p, a, np.sqrt(b), self.symmetric)

    def ppf(self, u):
        """Germ values of probabilities ``u`` (the germ's inverse CDF)."""
        if self.family == "legendre":
            return np.asarray(u, dtype=float)
        return self.distribution.ppf(u)


LEGENDRE = Germ("legendre")


def as_germs(germ, dim):
    """``None``, a family name, a :class:`Germ`, or one of those per variable → tuple of Germ."""
    if germ is None:
        return (LEGENDRE,) * dim
    if isinstance(germ, str | Germ):
        germ = [germ] * dim
    try:
        items = list(germ)
    except TypeError as e:
        raise TypeError(
            f"`germ` must be a family name, a Germ or a sequence of them, got {germ!r}"
        ) from e
    if len(items) != dim:
        raise ValueError(f"`germ` must give one germ per variable ({dim}), got {len(items)}")
    out = []
    for g in items:
        if isinstance(g, Germ):
            out.append(g)
        elif isinstance(g, str):
            out.append(Germ(g))
        else:
            raise TypeError(f"`germ` entries must be family names or Germ, got {g!r}")
    return tuple(out)
