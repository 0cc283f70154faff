"""Own-law polynomials (arbitrary polynomial chaos) of any continuous marginal.

For a law with no Askey family (a truncated normal, a triangular, a user's
``rv_continuous``), the orthonormal polynomials of the law itself make a model that is
polynomial in the input exactly representable (Oladyshkin & Nowak 2012; Soize & Ghanem
2004; OpenTURNS' ``AdaptiveStieltjesAlgorithm``). They are built on the standardised
variable :math:`g = (x - \\mu)/\\sigma`, from its monic three-term recurrence

.. math:: \\pi_{k+1}(g) = (g - a_k)\\,\\pi_k(g) - b_k\\,\\pi_{k-1}(g),

whose coefficients come from the discretized Stieltjes procedure (Gautschi 2004,
*Orthogonal Polynomials: Computation and Approximation*, §2.2.3.1) on a discrete measure
that reproduces the law's moments: an adaptive composite Gauss-Legendre rule in the
normal score :math:`z = \\Phi^{-1}(F(x))`, :math:`\\mathbb E[h(X)] = \\int h(F^{-1}(\\Phi(z)))
\\varphi(z)\\,dz` on :math:`|z| \\le 12` (the mass beyond is below 1e-32), whose panels are
halved until each panel's 20- and 10-point rules agree on the moments needed. Only
``ppf`` (and ``isf`` in the upper tail) of the law is used, so any law with an inverse
CDF works, including ones with kinks in their density (the panels refine around them).

The Gauss rules of these polynomials (Golub & Welsch 1969: the eigenvalues of the Jacobi
matrix) serve quadrature fits, and their triple products are read off the recurrence
exactly as for the Askey families.

The moment problem must be determinate for the polynomials to be dense in
:math:`L^2`: true for bounded laws and laws with tails as light as a normal's, not for a
lognormal (whose own polynomials still represent a model polynomial in it exactly, but
may converge slowly on other models; its default stays the Hermite germ).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from .germs import Germ
from .quadrature import gauss_golub_welsch, gauss_legendre

__all__ = ["OwnGerm", "stieltjes"]

# normal-score range of the discrete measure, and its panel rules
_Z_MAX = 12.0
_PANELS0 = 48
_NODES_HI, _NODES_LO = 20, 10
_MAX_PANELS = 512
_RTOL = 1e-13


_HI = gauss_legendre(_NODES_HI)
_LO = gauss_legendre(_NODES_LO)


def _law_at_normal(law, z):
    """x = F^{-1}(Phi(z)), through the survival function for z > 0."""
    with np.errstate(all="ignore"):
        lo = law.ppf(special.ndtr(np.minimum(z, 0.0)))
        hi = law.isf(special.ndtr(-np.maximum(z, 0.0)))
    return np.where(z <= 0, lo, hi)


def _panel_rule(law, edges, rule):
    t, w = rule
    a, b = edges[:-1, None], edges[1:, None]
    z = (a + (b - a) * t[None, :]).ravel()
    wz = ((b - a) * w[None, :]).ravel() * np.exp(-0.5 * z**2) / np.sqrt(2.0 * np.pi)
    return z, _law_at_normal(law, z), wz


def discrete_measure(law, degree, name="x"):
    """Nodes and probability weights reproducing the law's moments up to ``degree``.

    Parameters
    ----------
    law : object with ``ppf`` and ``isf``
    degree : int
        Highest moment the rule must integrate (in the standardised variable).
    name : str
        The input's name, for error messages.

    Returns
    -------
    x : (M,) ndarray
        Nodes on the law's own scale.
    w : (M,) ndarray
        Positive weights summing to 1.
    """
    edges = np.linspace(-_Z_MAX, _Z_MAX, _PANELS0 + 1)
    while True:
        _, xh, wh = _panel_rule(law, edges, _HI)
        if not np.all(np.isfinite(xh)):
            raise ValueError(
                f"input {name!r}: its ppf returned non-finite values inside (0, 1), so its "
                "own polynomials cannot be built; check the law's parameters"
            )
        _, xl, wl = _panel_rule(law, edges, _LO)
        wsum = wh.sum()
        mu = (wh @ xh) / wsum
        sd = np.sqrt(max((wh @ (xh - mu) ** 2) / wsum, 0.0))
        if not sd > 0:
            raise ValueError(f"input {name!r} has zero variance: it is a constant, not an input")
        gh = ((xh - mu) / sd).reshape(len(edges) - 1, -1)
        gl = ((xl - mu) / sd).reshape(len(edges) - 1, -1)
        Wh = wh.reshape(gh.shape)
        Wl = wl.reshape(gl.shape)
        # high monomials only differ in round-off once the low ones agree: test to 16
        k = np.arange(min(degree, 16) + 1)
        mh = np.einsum("pq,pqk->pk", Wh, gh[..., None] ** k)
        ml = np.einsum("pq,pqk->pk", Wl, gl[..., None] ** k)
        scale = np.maximum(np.abs(mh).sum(axis=0), 1.0)
        bad = np.any(np.abs(mh - ml) > _RTOL * scale, axis=1)
        if not bad.any() or len(edges) - 1 >= _MAX_PANELS:
            return xh, wh / wsum
        mid = 0.5 * (edges[:-1] + edges[1:])[bad]
        edges = np.sort(np.concatenate([edges, mid]))


def stieltjes(x, w, n):
    """Monic recurrence coefficients of the discrete measure ``(x, w)``: a_0..a_{n-1}, b_0..b_{n-1}.

    The discretized Stieltjes procedure (Gautschi 2004, §2.2.3.1) on orthonormal vectors,
    :math:`a_k = \\sum_q w_q x_q p_k(x_q)^2`, :math:`\\sqrt{b_{k+1}}\\,p_{k+1} = (x - a_k) p_k -
    \\sqrt{b_k}\\,p_{k-1}`, with one re-orthogonalisation against the earlier vectors per
    step (classical Gram-Schmidt twice is enough, Giraud et al. 2005). ``b_0 = 1``.
    """
    M = len(x)
    if n > M // 4:
        raise ValueError(f"{n} recurrence coefficients need more than {M} nodes")
    sw = np.sqrt(w)
    P = np.zeros((n + 1, M))
    P[0] = sw / np.linalg.norm(sw)
    a, b = np.zeros(n), np.zeros(n)
    b[0] = 1.0
    for k in range(n):
        a[k] = np.sum(x * P[k] ** 2)
        v = (x - a[k]) * P[k] - (np.sqrt(b[k]) * P[k - 1] if k > 0 else 0.0)
        v -= P[: k + 1].T @ (P[: k + 1] @ v)
        nv = np.linalg.norm(v)
        if k + 1 < n:
            b[k + 1] = nv**2
        P[k + 1] = v / nv
    return a, b


class OwnGerm(Germ):
    """The standardised input :math:`g = (x - \\mu)/\\sigma` with its own orthonormal polynomials.

    A :class:`~ecfm_uq.chaos.germs.Germ` of family ``"own"`` (``recurrence``, ``table``,
    ``gauss``, ``triple``, ``ppf``, ``support``) for the basis, designs and quadrature;
    two own-law germs are equal when built from the same law (same label, moments and
    recurrence).

    Parameters
    ----------
    law : object with ``ppf`` and ``isf`` (and ``support``)
    name : str
        The input's name (error messages).
    label : str
        The law's label (repr).
    degree : int
        Initial number of recurrence coefficients (grown on demand).
    """

    family = "own"
    params = ()
    symmetric = False

    def __init__(self, law, name="x", label="law", degree=32):
        self.law = law
        self.name = name
        self.label = label
        self._n = 0
        self._extend(degree)
        lo, hi = (float(v) for v in law.support())
        self.support = ((lo - self.mean) / self.std, (hi - self.mean) / self.std)

    def _extend(self, n):
        if self._n == 0:
            # one discrete measure per law (its moment test stops at degree 16, so a
            # larger degree would only refine it further in round-off)
            x, w = discrete_measure(self.law, 2 * n + 2, self.name)
            self.mean = float(w @ x)
            self.std = float(np.sqrt(w @ (x - self.mean) ** 2))
            self._g, self._w = (x - self.mean) / self.std, w
        self._a, self._b = stieltjes(self._g, self._w, n)
        self._n = n

    def __repr__(self):
        return f"OwnGerm({self.label})"

    def __eq__(self, other):
        # the same law gives the same (deterministic) measure and recurrence
        if not isinstance(other, OwnGerm):
            return NotImplemented
        n = min(self._n, other._n)
        return (
            self is other
            or (self.label, self.mean, self.std) == (other.label, other.mean, other.std)
            and np.array_equal(self._a[:n], other._a[:n])
            and np.array_equal(self._b[:n], other._b[:n])
        )

    def __hash__(self):
        return hash(("own", self.label, self.mean, self.std))

    def recurrence(self, n):
        """Monic recurrence coefficients of the standardised law (``b_0 = 1``)."""
        if n > self._n:
            self._extend(max(n, 2 * self._n))
        return self._a[:n].copy(), self._b[:n].copy()

    def table(self, x, p):
        """Orthonormal values ``V[q, m]`` = :math:`\\psi_m(x_q)`, shape (n, p + 1)."""
        from ._kernels import orthonormal_table

        a, b = self.recurrence(p + 1)
        return orthonormal_table(np.ascontiguousarray(x, dtype=float), p, a, np.sqrt(b))

    def gauss(self, n):
        """n-point Gauss rule of the law (Golub-Welsch): standardised nodes, weights summing to 1."""
        return gauss_golub_welsch(*self.recurrence(n))

    def triple(self, p, normalized=True):
        """Exact table :math:`t_{ijk} = \\mathbb E[\\psi_i\\psi_j\\psi_k]` from the recurrence."""
        from ._kernels import recurrence_triple_1d

        if not normalized:
            raise ValueError(f"only the Legendre germ has an unnormalised basis, not {self!r}")
        a, b = self.recurrence(2 * p + 2)
        return recurrence_triple_1d(p, a, np.sqrt(b), False)

    def ppf(self, u):
        """Germ values of probabilities ``u``: the standardised inverse CDF of the law."""
        return (np.asarray(self.law.ppf(u), dtype=float) - self.mean) / self.std

    def to_chaospy(self):
        raise ValueError(f"the own-law germ of {self.label} has no chaospy equivalent")
