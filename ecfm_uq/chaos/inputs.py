"""Model inputs as distributions, mapped to the germ of the chaos basis.

:class:`Inputs` takes any continuous marginals (scipy.stats frozen or chaospy
distributions) and, optionally, a Gaussian copula (Nataf) given by its correlation
matrix; each marginal is matched to its Askey germ or reached through an isoprobabilistic
transform (:mod:`ecfm_uq.chaos.marginals`). Dependent inputs are all expanded on
independent standard normal germs :math:`\\xi`: :math:`z = L\\xi` with
:math:`LL^T = R`, then :math:`x_k = F_k^{-1}(\\Phi(z_k))`.

:class:`UniformInputs` is the uniform case, kept as it was:

The chaos basis lives on the germ :math:`\\omega \\sim \\mathcal U(0, 1)^d`. A user's model
takes its inputs on their own ranges, :math:`x_k \\sim \\mathcal U(a_k, b_k)` independent,
and the affine map

.. math:: x_k = a_k + (b_k - a_k)\\,\\omega_k, \\qquad \\omega_k = (x_k - a_k)/(b_k - a_k)

carries one to the other. Because the map is affine, Legendre polynomials in
:math:`\\omega` are Legendre polynomials in :math:`x` and every statistic (moments, Sobol
indices, quantiles) is the same in either variable.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy import special

from .._validation import as_finite_array, rng_from_seed
from .germs import LEGENDRE, Germ
from .marginals import as_marginal

__all__ = ["Inputs", "UniformInputs", "as_inputs", "draw_germs"]


class Inputs:
    """Model inputs: continuous marginals, independent or joined by a Gaussian copula.

    Parameters
    ----------
    marginals : sequence of distributions
        One per input: ``scipy.stats`` frozen distributions (``norm(1, 0.2)``,
        ``lognorm(0.3, scale=2)``, ``gamma(2.5)``, ``beta(2, 3)``, ``weibull_min(1.5)``,
        ``truncnorm(...)``, ...) or 1-D chaospy distributions. Discrete laws are refused.
    correlation : (dim, dim) array_like, optional
        The correlation matrix :math:`R` of the Gaussian copula (the correlation of the
        normal scores :math:`z_k = \\Phi^{-1}(F_k(x_k))`; for normal marginals it is the
        inputs' own correlation). Symmetric, unit diagonal, positive definite. ``None``:
        independent inputs.
    names : sequence of str, optional
        Input names (default ``x0, x1, ...``).
    germ : None, "own", "transform" or a sequence of them, optional
        ``"own"``: expand the input on the orthonormal polynomials of its own law
        (arbitrary polynomial chaos, :mod:`ecfm_uq.chaos.ownlaw`; a model polynomial in
        the input is then represented exactly). ``"transform"``: the isoprobabilistic
        transform to a uniform or normal germ (the only route up to v0.3).
        ``None`` (default): the Askey germ for uniform, normal, gamma and beta inputs;
        own polynomials for other laws of bounded support (triangular, truncated on both
        sides, a custom bounded ``rv_continuous``) and for truncated normals (their
        moment problems are determinate, so the polynomials are dense); the transform for
        the rest (lognormal, Weibull, Gumbel, ...: own polynomials on request). One value
        for every input or one per input; independent inputs only (dependent ones are
        expanded on independent standard normals).

    Attributes
    ----------
    marginals : tuple of Marginal
    germs : tuple of Germ
        The germ of each chaos variable: the marginal's Askey germ for independent
        inputs, the standard normal for every variable of dependent inputs.
    correlation : (dim, dim) ndarray or None
    dependent : bool
    affine : bool
        Independent inputs that are all affine images of their germs (uniform, normal,
        gamma, beta): a PCE is then a polynomial in the inputs themselves.
    dim : int
    names : tuple of str

    Raises
    ------
    TypeError
        A discrete or unknown distribution (naming the input).
    ValueError
        A correlation matrix that is misshaped, not symmetric, without unit diagonal or
        not positive definite.

    Examples
    --------
    >>> from scipy import stats
    >>> inputs = Inputs([stats.norm(1.0, 0.1), stats.lognorm(0.25)], names=["load", "E"])
    >>> [g.family for g in inputs.germs]
    ['hermite', 'hermite']
    >>> inputs.from_germ([[1.0, 0.0]]).tolist()
    [[1.1, 1.0]]
    """

    def __init__(self, marginals, correlation=None, names=None, germ=None):
        if type(marginals).__module__.startswith("chaospy") and len(marginals) > 1:
            if getattr(marginals, "stochastic_dependent", False):
                raise TypeError(
                    f"`marginals` is a dependent chaospy distribution ({type(marginals).__name__}); "
                    "build its inputs with Inputs.from_chaospy(dist) (MvNormal), or give the "
                    "marginals and a `correlation`"
                )
            marginals = list(marginals)  # a chaospy.J / Iid of 1-D laws
        elif _is_distribution(marginals):
            marginals = [marginals]
        try:
            items = list(marginals)
        except TypeError as e:
            raise TypeError(
                f"`marginals` must be a sequence of distributions, got {type(marginals).__name__}"
            ) from e
        if not items:
            raise ValueError("`marginals` must hold at least one distribution")
        if names is None:
            names = [f"x{k}" for k in range(len(items))]
        names = tuple(str(n) for n in names)
        if len(names) != len(items):
            raise ValueError(f"`names` must hold {len(items)} names, got {len(names)}")
        self.names = names
        self.marginals = tuple(as_marginal(d, n) for d, n in zip(items, names, strict=True))
        self.correlation = None if correlation is None else self._check_correlation(correlation)
        choice = self._check_germ(germ)
        if any(c == "own" for c in choice) and self.correlation is not None:
            raise ValueError(
                "`germ='own'` is for independent inputs; dependent inputs (a `correlation`) "
                "are expanded on independent standard normals"
            )
        if self.correlation is None:
            self.marginals = tuple(
                m.own(n) if c == "own" or (c is None and m.own_by_default) else m
                for m, n, c in zip(self.marginals, names, choice, strict=True)
            )
        self.dependent = self.correlation is not None and not np.array_equal(
            self.correlation, np.eye(self.dim)
        )
        if self.dependent:
            self._L = np.linalg.cholesky(self.correlation)
            self.germs = (Germ("hermite"),) * self.dim
        else:
            self.correlation = None
            self.germs = tuple(m.germ for m in self.marginals)
        self.affine = not self.dependent and all(m.affine for m in self.marginals)

    def _check_germ(self, germ):
        """``germ`` → one entry per input: None, "own" or "transform"."""
        d = len(self.marginals)
        items = [germ] * d if germ is None or isinstance(germ, str) else list(germ)
        if len(items) != d:
            raise ValueError(f"`germ` must give one entry per input ({d}), got {len(items)}")
        for g in items:
            if g is not None and g not in ("own", "transform"):
                raise ValueError(
                    "`germ` entries must be None (the default), 'own' (the law's own "
                    f"polynomials) or 'transform' (to a uniform or normal germ), got {g!r}"
                )
        return items

    def _check_correlation(self, correlation):
        d = len(self.marginals)
        R = as_finite_array("correlation", correlation)
        if R.shape != (d, d):
            raise ValueError(
                f"`correlation` must have shape ({d}, {d}), one row per input, got {R.shape}"
            )
        if not np.allclose(R, R.T, rtol=0, atol=1e-12):
            raise ValueError("`correlation` must be symmetric")
        if not np.allclose(np.diag(R), 1.0, rtol=0, atol=1e-12):
            raise ValueError(f"`correlation` must have a unit diagonal, got {np.diag(R)}")
        eig = np.linalg.eigvalsh(0.5 * (R + R.T))
        if eig.min() <= 1e-12:
            raise ValueError(
                f"`correlation` is not positive definite (smallest eigenvalue {eig.min():.3g}): "
                "no Gaussian copula has it; check the entries (|r| < 1, consistent triples) or "
                "drop an input that is a function of the others"
            )
        return 0.5 * (R + R.T)

    @property
    def dim(self):
        """Number of inputs."""
        return len(self.marginals)

    def __repr__(self):
        rows = ", ".join(f"{n}~{m!r}" for n, m in zip(self.names, self.marginals, strict=True))
        dep = "" if not self.dependent else ", Gaussian copula"
        return f"Inputs({rows}{dep})"

    def __eq__(self, other):
        if not isinstance(other, Inputs) or isinstance(other, UniformInputs):
            return NotImplemented
        same_r = (self.correlation is None and other.correlation is None) or (
            self.correlation is not None
            and other.correlation is not None
            and np.array_equal(self.correlation, other.correlation)
        )
        return self.marginals == other.marginals and same_r

    __hash__ = None

    def _points(self, name, value):
        arr = as_finite_array(name, value)
        if arr.ndim == 1 and self.dim == 1:
            arr = arr[:, None]
        elif arr.ndim == 1 and arr.shape[0] == self.dim:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            raise ValueError(f"`{name}` must have shape (n, {self.dim}), got {arr.shape}")
        return arr

    def from_germ(self, omega):
        """Input points of germ points (one column per chaos variable).

        Parameters
        ----------
        omega : (n, dim) array_like

        Returns
        -------
        x : (n, dim) ndarray
        """
        g = self._points("omega", omega)
        if self.dependent:
            z = g @ self._L.T
            cols = [m.from_normal(z[:, k]) for k, m in enumerate(self.marginals)]
        else:
            cols = [m.from_germ(g[:, k]) for k, m in enumerate(self.marginals)]
        return np.column_stack(cols)

    def to_germ(self, x):
        """Germ points of input points.

        Raises
        ------
        ValueError
            If a point lies outside an input's support.
        """
        x = self._points("x", x)
        for k, m in enumerate(self.marginals):
            lo, hi = m.support
            bad = (x[:, k] < lo) | (x[:, k] > hi)
            if bad.any():
                q = int(np.argmax(bad))
                raise ValueError(
                    f"`x` point {q} has {self.names[k]} = {x[q, k]:g} outside the support "
                    f"[{lo:g}, {hi:g}] of its law {m!r}"
                )
        if self.dependent:
            z = np.column_stack([m.to_normal(x[:, k]) for k, m in enumerate(self.marginals)])
            return sla.solve_triangular(self._L, z.T, lower=True).T
        return np.column_stack([m.to_germ(x[:, k]) for k, m in enumerate(self.marginals)])

    def sample(self, n, seed=None):
        """``n`` random input points (through independent germ draws)."""
        g = draw_germs(self.germs, n, seed)
        return self.from_germ(g)

    def to_chaospy(self):
        """The inputs as a chaospy distribution (a ``chaospy.J``, or ``MvNormal``)."""
        import chaospy

        if self.dependent:
            if all(m.kind == "normal" for m in self.marginals):
                s = np.array([m.scale for m in self.marginals])
                mu = [m.loc for m in self.marginals]
                return chaospy.MvNormal(mu, self.correlation * np.outer(s, s))
            raise ValueError(
                "dependent non-normal inputs have no chaospy equivalent here; use "
                "chaospy.Nataf or sample through Inputs.sample"
            )
        return chaospy.J(*[m.to_chaospy() for m in self.marginals])

    @classmethod
    def from_samples(cls, samples, names=None):
        """Inputs that reproduce samples: empirical marginals joined by a Gaussian copula.

        Each marginal is the continuous law whose CDF interpolates the empirical one
        linearly between consecutive order statistics (``scipy.stats.rv_histogram`` with
        the sorted samples as edges: equal mass between neighbours; its support is the
        samples' range, so no value beyond them is drawn), reached from the germ as any
        bounded law (its own polynomials alone, the normal-score transform when joined).
        The copula's correlation is that of the normal scores
        :math:`\\Phi^{-1}(\\mathrm{rank}/(n + 1))` of the columns (Nataf): for normal
        samples, their correlation.

        Parameters
        ----------
        samples : (n, dim) array_like
            At least 10 finite points; a 1-D array is one input.
        names : sequence of str, optional

        Returns
        -------
        Inputs

        Raises
        ------
        ValueError
            Misshaped or non-finite ``samples``, fewer than 10, a constant column.
        """
        return _empirical_inputs(cls, samples, names)

    @classmethod
    def from_chaospy(cls, dist, names=None):
        """Inputs from a chaospy distribution: ``J``/``Iid`` of 1-D laws, or ``MvNormal``."""
        import chaospy

        if not isinstance(dist, chaospy.Distribution):
            raise TypeError(f"`dist` must be a chaospy distribution, got {type(dist).__name__}")
        if isinstance(dist, chaospy.MvNormal):
            mu = np.asarray(chaospy.E(dist), dtype=float).ravel()
            C = np.asarray(chaospy.Cov(dist), dtype=float).reshape(len(mu), len(mu))
            s = np.sqrt(np.diag(C))
            from scipy import stats

            marg = [stats.norm(m, sk) for m, sk in zip(mu, s, strict=True)]
            return cls(marg, correlation=C / np.outer(s, s), names=names)
        if getattr(dist, "stochastic_dependent", False):
            raise TypeError(
                f"`dist` is a dependent chaospy distribution ({type(dist).__name__}) other than "
                "MvNormal; give the marginals and the Gaussian copula's `correlation` to Inputs"
            )
        parts = [dist] if len(dist) == 1 and not isinstance(dist, chaospy.J) else list(dist)
        return cls(parts, names=names)


def _empirical_inputs(cls, samples, names):
    """:meth:`Inputs.from_samples`."""
    from scipy import stats

    x = as_finite_array("samples", samples)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] < 10:
        raise ValueError(
            f"`samples` must have shape (n, dim) with at least 10 points, got {x.shape}"
        )
    n, d = x.shape
    laws = []
    for k in range(d):
        edges = np.unique(x[:, k])
        if edges.size < 2:
            raise ValueError(
                f"`samples` column {k} is constant ({edges[0]:g}): a constant is not an "
                "input; drop it"
            )
        # equal mass between consecutive order statistics: the empirical CDF interpolated
        laws.append(stats.rv_histogram((np.ones(edges.size - 1), edges), density=False))
    if d == 1:
        return cls(laws, names=names)
    ranks = stats.rankdata(x, axis=0)
    z = special.ndtri(ranks / (n + 1.0))  # normal scores
    R = np.corrcoef(z, rowvar=False)
    return cls(laws, correlation=0.5 * (R + R.T), names=names)


def draw_germs(germs, n, seed=None):
    """``n`` independent draws of the germ variables, (n, dim).

    Uniform germs are ``Generator.random`` draws exactly (as in the uniform-only code);
    other germs are their inverse CDF of the same uniforms.
    """
    omega = rng_from_seed("seed", seed).random((n, len(germs)))
    for d, g in enumerate(germs):
        if g.family != "legendre":
            u = np.clip(omega[:, d], np.finfo(float).tiny, 1.0 - np.finfo(float).epsneg)
            omega[:, d] = g.ppf(u)
    return omega


class UniformInputs(Inputs):
    """Independent uniform inputs :math:`x_k \\sim \\mathcal U(a_k, b_k)`, ``k < dim``.

    Parameters
    ----------
    bounds : (dim, 2) array_like
        Rows ``(a_k, b_k)`` with ``a_k < b_k``, finite. A single pair ``(a, b)`` is one
        input.
    names : sequence of str, optional
        Input names (default ``x0, x1, ...``), used in reports and in the chaospy export.

    Attributes
    ----------
    bounds : (dim, 2) ndarray
    lower, upper, width : (dim,) ndarray
    dim : int
    names : tuple of str

    Raises
    ------
    ValueError
        If ``bounds`` is misshaped, non-finite, or some ``a_k >= b_k``.

    Examples
    --------
    >>> inputs = UniformInputs([(-np.pi, np.pi)] * 3)
    >>> inputs.from_germ([[0.5, 0.0, 1.0]]).round(6).tolist()
    [[0.0, -3.141593, 3.141593]]
    """

    def __init__(self, bounds, names=None):
        arr = as_finite_array("bounds", bounds)
        if arr.ndim == 1 and arr.shape == (2,):
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
            raise ValueError(f"`bounds` must have shape (dim, 2), rows (a_k, b_k), got {arr.shape}")
        bad = np.flatnonzero(arr[:, 0] >= arr[:, 1])
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"`bounds` row {k} is ({arr[k, 0]:g}, {arr[k, 1]:g}): each input needs a < b; "
                "pass (lower, upper)"
            )
        self.bounds = arr.copy()
        self.bounds.setflags(write=False)
        if names is None:
            names = [f"x{k}" for k in range(arr.shape[0])]
        names = tuple(str(n) for n in names)
        if len(names) != arr.shape[0]:
            raise ValueError(f"`names` must hold {arr.shape[0]} names, got {len(names)}")
        self.names = names
        self.germs = (LEGENDRE,) * arr.shape[0]
        self.correlation = None
        self.dependent = False
        self.affine = True

    @property
    def marginals(self):
        """Each input as a :class:`~ecfm_uq.chaos.marginals.Marginal` (uniform)."""
        from scipy import stats

        return tuple(
            as_marginal(stats.uniform(a, b - a), n)
            for n, (a, b) in zip(self.names, self.bounds, strict=True)
        )

    @property
    def dim(self):
        """Number of inputs."""
        return self.bounds.shape[0]

    @property
    def lower(self):
        return self.bounds[:, 0]

    @property
    def upper(self):
        return self.bounds[:, 1]

    @property
    def width(self):
        return self.bounds[:, 1] - self.bounds[:, 0]

    def __repr__(self):
        rows = ", ".join(
            f"{n}~U({a:g}, {b:g})" for n, (a, b) in zip(self.names, self.bounds, strict=True)
        )
        return f"UniformInputs({rows})"

    def __eq__(self, other):
        if not isinstance(other, UniformInputs):
            return NotImplemented
        return np.array_equal(self.bounds, other.bounds)

    __hash__ = None

    def to_germ(self, x):
        """Germ points :math:`\\omega = (x - a)/(b - a)`.

        Parameters
        ----------
        x : (n, dim) array_like
            Points in the inputs' box (a single point of shape (dim,) is accepted).

        Returns
        -------
        omega : (n, dim) ndarray

        Raises
        ------
        ValueError
            If a point lies outside the box (beyond round-off).
        """
        x = self._points("x", x)
        omega = (x - self.lower) / self.width
        if omega.size and (omega.min() < -1e-12 or omega.max() > 1 + 1e-12):
            q, k = np.unravel_index(np.argmax(np.maximum(-omega, omega - 1)), omega.shape)
            raise ValueError(
                f"`x` point {q} has {self.names[k]} = {x[q, k]:g} outside its range "
                f"[{self.lower[k]:g}, {self.upper[k]:g}]"
            )
        return np.clip(omega, 0.0, 1.0)

    def from_germ(self, omega):
        """Input points :math:`x = a + (b - a)\\,\\omega`.

        Parameters
        ----------
        omega : (n, dim) array_like
            Germ points in [0, 1]^dim.

        Returns
        -------
        x : (n, dim) ndarray
        """
        omega = self._points("omega", omega)
        return self.lower + self.width * omega

    @classmethod
    def from_chaospy(cls, dist):
        """Inputs from a chaospy distribution of independent uniforms.

        Parameters
        ----------
        dist : chaospy.Distribution
            A ``chaospy.Uniform`` or a joint ``chaospy.J`` / ``chaospy.Iid`` of
            ``chaospy.Uniform`` s.

        Raises
        ------
        TypeError
            If ``dist`` is not a chaospy distribution, or has a non-uniform component
            (the basis is Legendre, orthogonal for uniform inputs only).
        """
        import chaospy

        if not isinstance(dist, chaospy.Distribution):
            raise TypeError(f"`dist` must be a chaospy distribution, got {type(dist).__name__}")
        parts = [dist] if isinstance(dist, chaospy.Uniform) else list(dist)
        for k, d in enumerate(parts):
            if not isinstance(d, chaospy.Uniform):
                raise TypeError(
                    f"`dist` component {k} is {type(d).__name__}: the basis is "
                    "Legendre, orthogonal for uniform inputs only; pass a chaospy.J of "
                    "chaospy.Uniform(a, b) (or transform the input to a uniform yourself)"
                )
        bounds = [(float(d.lower[0]), float(d.upper[0])) for d in parts]
        return cls(bounds)

    def to_chaospy(self):
        """The same inputs as a chaospy joint distribution of ``chaospy.Uniform``."""
        import chaospy

        return chaospy.J(*[chaospy.Uniform(float(a), float(b)) for a, b in self.bounds])


def _is_distribution(obj):
    """A 1-D law: chaospy, scipy (frozen, unfrozen rv_continuous, new-style) or cdf + ppf."""
    from scipy import stats

    return (
        type(obj).__module__.startswith("chaospy")
        or isinstance(obj, stats.rv_continuous | stats.rv_discrete)
        or (hasattr(obj, "cdf") and (hasattr(obj, "ppf") or hasattr(obj, "icdf")))
    )


def as_inputs(inputs, dim=None):
    """``None``, :class:`Inputs`, bounds, distributions or a chaospy joint → inputs.

    Parameters
    ----------
    inputs : None, Inputs, UniformInputs, (dim, 2) array_like, chaospy.Distribution,
        scipy.stats frozen distribution (1-D, or ``multivariate_normal``) or a sequence
        of 1-D distributions
    dim : int, optional
        Required number of inputs.
    """
    if isinstance(inputs, dict):
        raise TypeError(
            f"`inputs` must be bounds, an Inputs or a list of distributions, got a dict of "
            f"{len(inputs)} entries; pass Inputs(list(d.values()), names=list(d)) to keep "
            "the names"
        )
    if inputs is None or isinstance(inputs, Inputs):
        out = inputs
    elif type(inputs).__module__.startswith("chaospy"):
        import chaospy

        parts = [inputs] if isinstance(inputs, chaospy.Uniform) else None
        if parts is None and not isinstance(inputs, chaospy.MvNormal):
            try:
                parts = list(inputs)
            except TypeError:
                parts = [inputs]
        if parts is not None and all(isinstance(d, chaospy.Uniform) for d in parts):
            out = UniformInputs.from_chaospy(inputs)  # the uniform-only path, unchanged
        else:
            out = _named(Inputs.from_chaospy, inputs)
    elif hasattr(inputs, "cov") and hasattr(inputs, "mean") and hasattr(inputs, "rvs"):
        # scipy.stats.multivariate_normal(mean, cov)
        from scipy import stats

        mu = np.atleast_1d(np.asarray(inputs.mean, dtype=float))
        C = np.atleast_2d(np.asarray(inputs.cov, dtype=float))
        s = np.sqrt(np.diag(C))
        marg = [stats.norm(m, sk) for m, sk in zip(mu, s, strict=True)]
        out = _named(Inputs, marg, correlation=C / np.outer(s, s))
    elif _is_distribution(inputs):
        out = _named(Inputs, [inputs])
    elif isinstance(inputs, list | tuple) and inputs and any(_is_distribution(d) for d in inputs):
        out = _named(Inputs, list(inputs))
    else:
        try:
            out = UniformInputs(inputs)
        except ValueError as e:
            raise ValueError(f"`inputs`: {e}") from e
    if out is not None and dim is not None and out.dim != dim:
        raise ValueError(f"`inputs` has {out.dim} variables but the basis has dim={dim}")
    return out


def check_moments(inputs, who, variance=True):
    """Refuse inputs whose law has no finite mean (or, with ``variance``, no finite
    variance): ``who`` estimates moments that do not exist for them.

    Raises
    ------
    ValueError
        Naming the input, its law, what ``who`` needs and what to do.
    """
    if inputs is None or isinstance(inputs, UniformInputs):
        return
    for name, m in zip(inputs.names, inputs.marginals, strict=True):
        missing = "mean" if not m.finite_mean else None
        if missing is None and variance and not m.finite_variance:
            missing = "variance"
        if missing is not None:
            needs = "a mean and a variance" if variance else "a mean"
            raise ValueError(
                f"input {name!r} ({m!r}) has no finite {missing}: {who} needs {needs} of "
                "every input (its estimates would be numbers without a limit); truncate the "
                "law (scipy.stats.truncate, truncnorm) or use one with finite moments"
            )


def _named(build, *args, **kwargs):
    """Build inputs, prefixing errors with the argument name ``inputs``."""
    try:
        return build(*args, **kwargs)
    except (TypeError, ValueError) as e:
        raise type(e)(f"`inputs`: {e}") from e
