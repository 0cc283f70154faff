"""Polynomial chaos expansions as objects: moments, Sobol indices, evaluation, sampling.

A PCE of an output :math:`y` (scalar, vector of sensors or field) on the germ
:math:`\\omega \\sim \\mathcal U(0, 1)^d` is

.. math:: y(\\omega) \\approx \\sum_{k=0}^{P-1} c_k\\,\\Psi_k(\\omega),

with the shifted Legendre basis of :class:`~ecfm_uq.chaos.ChaosBasis` (paper Section 3.3,
Eq. ``pce``; the statistics are Eq. ``stats``). Everything here is read off the
coefficients and the multi-indices :math:`\\alpha^{(k)}`, whoever computed them: the
stochastic Galerkin solver (:meth:`ecfm_uq.system.SteadySolution.pce`) or a non-intrusive
fit (:func:`ecfm_uq.chaos.fit_pce`).
"""

from __future__ import annotations

import numbers

import numpy as np
import scipy.sparse as sp

from .._validation import as_finite_array, check_choice, check_int
from ..memory import check_allocation, check_covariance
from ..plotting import sobol_bars
from .basis import ChaosBasis
from .inputs import UniformInputs, as_inputs, draw_germs
from .projection import project

__all__ = ["PolynomialChaosExpansion"]

# Rows of the (n, P) basis matrix formed at once when evaluating many points.
_EVAL_BLOCK_ENTRIES = 4_000_000
_KINDS = ("interaction", "closed", "total")


class PolynomialChaosExpansion:
    """A polynomial chaos expansion :math:`y(\\omega) = \\sum_k c_k \\Psi_k(\\omega)`.

    Parameters
    ----------
    basis : ChaosBasis
        The basis :math:`\\Psi_0, \\ldots, \\Psi_{P-1}` (orthonormal or not).
    coefficients : (P, *output_shape) array_like
        :math:`c_k`, one row per basis term; ``output_shape`` is ``()`` for a scalar
        output, ``(C,)`` for sensors, any shape for a field. (A Galerkin state
        :math:`\\Theta` is ``(N, P)``: pass ``Theta.T`` or use :meth:`from_galerkin`.)
    inputs : Inputs, UniformInputs, (dim, 2) bounds or distributions, optional
        The model inputs that the germ stands for, e.g. :math:`x_k \\sim \\mathcal U(a_k,
        b_k)` with :math:`x = a + (b - a)\\omega`, or any :class:`~ecfm_uq.chaos.Inputs`
        whose germs are the basis's (``basis.germs == inputs.germs``). ``None``: the
        inputs are the germ itself.

    Attributes
    ----------
    basis : ChaosBasis
    coefficients : (P, *output_shape) ndarray
    inputs : Inputs, UniformInputs or None
    output_shape : tuple
    diagnostics : dict
        Set by :func:`~ecfm_uq.chaos.fit_pce` (method, evaluations, errors); empty else.

    Notes
    -----
    With :math:`n_k = \\mathbb E[\\Psi_k^2]` (``basis.norms2``, ones when orthonormal) and
    :math:`\\Psi_0 = 1`,

    .. math::

        \\mathbb E[y] = c_0, \\qquad
        \\operatorname{Var}[y] = \\sum_{k \\ge 1} c_k^2 n_k, \\qquad
        \\operatorname{Cov}[y_i, y_j] = \\sum_{k \\ge 1} c_{ki} c_{kj} n_k.

    The Sobol (Hoeffding) decomposition groups the terms by the set of variables they
    depend on, :math:`\\mathrm{supp}\\,\\alpha = \\{i : \\alpha_i > 0\\}` (Sudret 2008):

    .. math::

        S_u = \\frac{1}{\\operatorname{Var}[y]} \\sum_{k:\\,\\mathrm{supp}\\,\\alpha^{(k)} = u}
              c_k^2 n_k, \\qquad
        T_i = \\frac{1}{\\operatorname{Var}[y]} \\sum_{k:\\,\\alpha^{(k)}_i > 0} c_k^2 n_k.

    These are exact for the expansion (no sampling). An output component of zero
    variance has no Sobol indices: the methods raise unless ``zero_variance`` gives the
    value to report there.

    Examples
    --------
    >>> basis = ChaosBasis(1, dim=2)
    >>> pce = PolynomialChaosExpansion(basis, [1.0, 2.0, 1.0])  # y = 1 + 2 L1(w1) + L1(w2)
    >>> float(pce.mean), float(pce.variance)
    (1.0, 5.0)
    >>> pce.first_order().tolist()
    [0.8, 0.2]
    """

    def __init__(self, basis, coefficients, inputs=None):
        if not isinstance(basis, ChaosBasis):
            raise TypeError(f"`basis` must be a ChaosBasis, got {type(basis).__name__}")
        self.basis = basis
        c = as_finite_array("coefficients", coefficients)
        if c.ndim == 0 or c.shape[0] != basis.size:
            raise ValueError(
                f"`coefficients` must have shape (P, *output_shape) with P = {basis.size} "
                f"rows (one per basis term), got {c.shape}; a Galerkin Theta (N, P) is "
                "passed as Theta.T or through PolynomialChaosExpansion.from_galerkin"
            )
        self.coefficients = c
        self.inputs = as_inputs(inputs, basis.dim)
        if self.inputs is not None and tuple(self.inputs.germs) != tuple(basis.germs):
            raise ValueError(
                f"`inputs` are expanded on the germs {list(self.inputs.germs)} but the basis "
                f"has {list(basis.germs)}; build the basis with germ=inputs.germs"
            )
        self.diagnostics = {}

    # -- construction ------------------------------------------------------------------
    @classmethod
    def from_galerkin(cls, system_or_basis, theta, inputs=None, observe=None):
        """The PCE of a stochastic Galerkin state :math:`\\Theta` (or of observations of it).

        Parameters
        ----------
        system_or_basis : GalerkinSystem or ChaosBasis
            The system (its ``basis``) or the basis the state is expanded on.
        theta : (N, P) array_like
            Galerkin coefficients :math:`\\Theta_{ik}`, rows spatial, columns chaos.
        inputs : optional
            As in the constructor.
        observe : (C, N) array_like or scipy.sparse matrix, optional
            Observation operator, e.g. the sensor matrix :math:`\\mathcal M`: the PCE is
            then of :math:`\\mathcal M\\theta(\\omega)` (C outputs) instead of the N states.

        Returns
        -------
        PolynomialChaosExpansion
            Coefficients ``theta.T`` (P, N) or ``(observe @ theta).T`` (P, C).
        """
        basis = getattr(system_or_basis, "basis", system_or_basis)
        if not isinstance(basis, ChaosBasis):
            raise TypeError(
                "`system_or_basis` must be a GalerkinSystem with a chaos basis or a "
                f"ChaosBasis, got {type(system_or_basis).__name__} (a deterministic system "
                "has no PCE)"
            )
        theta = as_finite_array("theta", theta, ndim=2)
        if theta.shape[1] != basis.size:
            raise ValueError(
                f"`theta` must have shape (N, P) with P = {basis.size}, got {theta.shape}"
            )
        pce = cls(basis, theta.T, inputs)
        return pce if observe is None else pce.linear_map(observe)

    @classmethod
    def from_chaospy(cls, poly, inputs=None, order=None, index_set="total"):
        """Project a chaospy/numpoly polynomial onto the Legendre basis (exactly).

        Parameters
        ----------
        poly : numpoly.ndpoly
            Polynomial (of any output shape) in the variables ``q0, ..., q{d-1}``, which
            are the inputs on their own ranges (or the germ when ``inputs`` is ``None``).
        inputs : optional
            As in the constructor; its ``dim`` is the number of variables.
        order : int, optional
            Order of the basis (default: the total degree of ``poly``, so the result is
            exact).
        index_set : {"total", "tensor"}

        Returns
        -------
        PolynomialChaosExpansion
            Coefficients by tensor Gauss-Legendre projection with ``order + 1`` points
            per variable, exact when ``poly`` lies in the basis span.
        """
        import numpoly

        poly = numpoly.polynomial(poly)
        inputs = as_inputs(inputs)
        names = [str(n) for n in poly.names] if poly.exponents.any() else []
        if inputs is None:
            dim = max([int(n[1:]) + 1 for n in names if n[1:].isdigit()] or [1])
        else:
            dim = inputs.dim
        allowed = {f"q{k}" for k in range(dim)}
        if not set(names) <= allowed:
            raise ValueError(
                f"`poly` uses variables {names}; expected a subset of "
                f"{sorted(allowed)} (one per input)"
            )
        degree = int(poly.exponents.sum(axis=1).max()) if poly.exponents.size else 0
        order = degree if order is None else check_int("order", order, minimum=0)
        germ = None if inputs is None else inputs.germs
        basis = ChaosBasis(order, dim, index_set=index_set, germ=germ)
        nodes, w = basis.quadrature(max(order, degree) + 1)
        x = nodes if inputs is None else inputs.from_germ(nodes)
        vals = poly(**{n: x[:, int(n[1:])] for n in names})
        vals = np.broadcast_to(np.asarray(vals, dtype=float), (*poly.shape, len(w)))
        y = np.moveaxis(vals, -1, 0)
        return cls(basis, project(basis, nodes, w, y), inputs)

    # -- shapes ------------------------------------------------------------------------
    @property
    def output_shape(self):
        """Shape of one output value."""
        return self.coefficients.shape[1:]

    @property
    def dim(self):
        """Number of random variables."""
        return self.basis.dim

    def __repr__(self):
        return (
            f"PolynomialChaosExpansion(order={self.basis.order}, dim={self.dim}, "
            f"P={self.basis.size}, output_shape={self.output_shape})"
        )

    def _flat(self):
        return self.coefficients.reshape(self.basis.size, -1)

    def linear_map(self, A):
        """The PCE of :math:`A y` for a (C, m) matrix acting on a vector output (m,).

        Parameters
        ----------
        A : (C, m) array_like or scipy.sparse matrix

        Returns
        -------
        PolynomialChaosExpansion
            Output shape ``(C,)``.
        """
        if len(self.output_shape) != 1:
            raise ValueError(
                f"`A` acts on vector outputs; this PCE has output shape {self.output_shape}"
            )
        m = self.output_shape[0]
        if sp.issparse(A):
            if A.shape[1] != m:
                raise ValueError(f"`A` must have shape (C, {m}), got {A.shape}")
            c = np.asarray((A @ self.coefficients.T).T)
        else:
            A = as_finite_array("A", A, ndim=2)
            if A.shape[1] != m:
                raise ValueError(f"`A` must have shape (C, {m}), got {A.shape}")
            c = self.coefficients @ A.T
        return type(self)(self.basis, c, self.inputs)

    # -- moments -----------------------------------------------------------------------
    @property
    def mean(self):
        """:math:`\\mathbb E[y] = c_0` (times :math:`\\Psi_0 = 1`), shape ``output_shape``."""
        return self.coefficients[0].copy()

    def _contributions(self):
        """(P, m) partial variances :math:`c_k^2 n_k` (row 0 is the mean's, zeroed)."""
        c = self._flat()
        out = c**2 * np.asarray(self.basis.norms2)[:, None]
        out[0] = 0.0
        return out

    @property
    def variance(self):
        """:math:`\\operatorname{Var}[y] = \\sum_{k\\ge1} c_k^2 n_k` (``output_shape``); refused on an input of infinite variance."""
        self._check_finite_variance(np.asarray(self.basis.indices) > 0)
        return self._contributions().sum(axis=0).reshape(self.output_shape)

    @property
    def std(self):
        """Standard deviation, shape ``output_shape``."""
        return np.sqrt(self.variance)

    @property
    def covariance(self):
        """:math:`\\operatorname{Cov}[y_i, y_j]`, shape ``output_shape + output_shape``."""
        c = self._flat()[1:]
        check_covariance(c.shape[1], "output covariance", "pce.variance", copies=1)
        n2 = np.asarray(self.basis.norms2)[1:, None]
        cov = c.T @ (c * n2)
        return cov.reshape(self.output_shape + self.output_shape)

    # -- Sobol indices -----------------------------------------------------------------
    def _normalize(self, parts, zero_variance):
        """Divide (r, m) partial variances by Var; handle constant outputs explicitly."""
        contrib = self._contributions()
        var = contrib.sum(axis=0)
        second = var + self._flat()[0] ** 2
        # A variance at the round-off level of the second moment is a constant output.
        const = var <= (1e-14) ** 2 * second
        if const.any():
            if isinstance(zero_variance, str) and zero_variance == "raise":
                j = int(np.flatnonzero(const)[0])
                where = np.unravel_index(j, self.output_shape) if self.output_shape else ()
                raise ValueError(
                    f"output component {tuple(int(i) for i in where)} has zero variance "
                    "(a constant output): its Sobol indices are undefined; pass "
                    "`zero_variance=0.0` (or another number) to report that value there"
                )
            if isinstance(zero_variance, bool) or not isinstance(zero_variance, numbers.Real):
                raise TypeError(
                    f"`zero_variance` must be 'raise' or a number, got {zero_variance!r}"
                )
        with np.errstate(divide="ignore", invalid="ignore"):
            out = parts / np.where(const, 1.0, var)
        out[:, const] = float(zero_variance) if const.any() else 0.0
        return out.reshape((parts.shape[0], *self.output_shape))

    @property
    def _support(self):
        if self.inputs is not None and self.inputs.dependent:
            raise ValueError(
                "Sobol indices are not defined for dependent `inputs` (a Gaussian copula): "
                "the variance of y has no unique split among correlated inputs, and the "
                "indices of the chaos variables are those of independent normal scores "
                "(the inputs decorrelated in one order), not of the inputs. Mean, variance, "
                "quantiles and densities are exact; for sensitivities fit with independent "
                "inputs or use sobol_germ()"
            )
        self._check_index_memory()
        support = np.asarray(self.basis.indices) > 0
        self._check_finite_variance(support)
        return support

    def _check_index_memory(self):
        """Sobol indices hold about four (P, m) arrays (partial variances, shares, sums)."""
        P, m = self._flat().shape
        check_allocation(
            8.0 * 4 * P * m,
            f"the Sobol indices of a {m}-value expansion of {P} terms",
            "take the indices of the components you need: "
            "PolynomialChaosExpansion(pce.basis, pce.coefficients[:, idx], pce.inputs)",
        )

    def _check_finite_variance(self, support):
        """Refuse indices when the output depends on an input without finite variance."""
        if self.inputs is None or isinstance(self.inputs, UniformInputs):
            return
        contrib = self._contributions()
        # a variable carrying less than 1e-12 of every component's variance is round-off
        share = contrib / np.maximum(contrib.sum(axis=0), np.finfo(float).tiny)
        used = support[np.any(share > 1e-12, axis=1)].any(axis=0)
        for k, m in enumerate(self.inputs.marginals):
            if used[k] and not m.finite_variance:
                raise ValueError(
                    f"input {self.inputs.names[k]!r} ({m!r}) has no finite variance, so the "
                    "output's variance (and its Sobol indices) may not exist: the expansion "
                    "has only its truncated polynomial's. If the model is bounded in it, use "
                    "the germ's: PolynomialChaosExpansion(pce.basis, pce.coefficients)"
                )

    def sobol_germ(self, kind="first", zero_variance="raise"):
        """First-order or total indices of the chaos (germ) variables, shape (dim, ...).

        For independent inputs these are :meth:`first_order` and :meth:`total`. For
        dependent inputs they are the indices of the independent standard normals
        :math:`\\xi = L^{-1}z` behind the Gaussian copula, variable k being the part of
        normal score :math:`z_k` not explained by :math:`z_0..z_{k-1}` (Cholesky order):
        the "full and independent" indices of Mara & Tarantola (2012) for one ordering,
        not Sobol indices of the inputs.

        Parameters
        ----------
        kind : {"first", "total"}
        zero_variance : "raise" or float
        """
        kind = check_choice("kind", kind, ("first", "total"))
        self._check_index_memory()
        s = np.asarray(self.basis.indices) > 0
        if kind == "first":
            s = s & (s.sum(axis=1) == 1)[:, None]
        return self._normalize(s.T.astype(float) @ self._contributions(), zero_variance)

    def first_order(self, zero_variance="raise"):
        """First-order Sobol indices :math:`S_i`, shape ``(dim, *output_shape)``.

        Parameters
        ----------
        zero_variance : "raise" or float
            What a constant output component gets: ``"raise"`` (default) raises
            ValueError naming the component; a number is reported as its index.
        """
        s = self._support
        only = s & (s.sum(axis=1) == 1)[:, None]
        return self._normalize(only.T.astype(float) @ self._contributions(), zero_variance)

    def total(self, zero_variance="raise"):
        """Total Sobol indices :math:`T_i`, shape ``(dim, *output_shape)``.

        Parameters
        ----------
        zero_variance : "raise" or float
            As in :meth:`first_order`.
        """
        s = self._support
        return self._normalize(s.T.astype(float) @ self._contributions(), zero_variance)

    def sobol(self, subset, kind="interaction", zero_variance="raise"):
        """Sobol index of a subset :math:`u` of the variables.

        Parameters
        ----------
        subset : int or sequence of int
            Variable numbers (0-based) forming :math:`u`.
        kind : {"interaction", "closed", "total"}
            ``"interaction"``: :math:`S_u`, the terms depending on exactly the variables
            in :math:`u`; ``"closed"``: :math:`S^{clo}_u = \\sum_{v \\subseteq u} S_v`, the
            variance explained by :math:`u` alone; ``"total"``:
            :math:`T_u = \\sum_{v \\cap u \\ne \\emptyset} S_v`.
        zero_variance : "raise" or float
            As in :meth:`first_order`.

        Returns
        -------
        ndarray of shape ``output_shape``
        """
        kind = check_choice("kind", kind, _KINDS)
        u = np.atleast_1d(np.asarray(subset))
        if u.size == 0 or u.dtype.kind not in "iu" or u.ndim != 1:
            raise ValueError(
                f"`subset` must be a non-empty sequence of variable numbers, got {subset!r}"
            )
        if np.any((u < 0) | (u >= self.dim)) or len(set(u.tolist())) != u.size:
            raise ValueError(
                f"`subset` must hold distinct variable numbers in [0, {self.dim - 1}], got {subset!r}"
            )
        s = self._support
        inside = np.zeros(self.dim, dtype=bool)
        inside[u] = True
        if kind == "interaction":
            mask = (s == inside).all(axis=1)
        elif kind == "closed":
            mask = ~(s & ~inside).any(axis=1)
        else:
            mask = (s & inside).any(axis=1)
        part = mask.astype(float)[None, :] @ self._contributions()
        return self._normalize(part, zero_variance)[0]

    def sobol_interactions(self, max_size=None, threshold=0.0, zero_variance="raise"):
        """All nonzero interaction indices :math:`S_u`, for a scalar-per-component report.

        Parameters
        ----------
        max_size : int, optional
            Largest :math:`|u|` reported (default all).
        threshold : float
            Omit subsets whose index is below this everywhere.

        Returns
        -------
        dict
            ``{u: S_u}`` with ``u`` a tuple of variable numbers and ``S_u`` of shape
            ``output_shape``; the values sum to 1 over all subsets.
        """
        s = self._support
        keys = [tuple(np.flatnonzero(row).tolist()) for row in s]
        groups = {}
        for k, key in enumerate(keys):
            if key and (max_size is None or len(key) <= max_size):
                groups.setdefault(key, []).append(k)
        contrib = self._contributions()
        out = {}
        for key in sorted(groups, key=lambda t: (len(t), t)):
            part = contrib[groups[key]].sum(axis=0)[None, :]
            val = self._normalize(part, zero_variance)[0]
            if np.max(np.abs(val), initial=0.0) >= threshold:
                out[key] = val
        return out

    def plot_sobol(self, ax=None, names=None, component=(), germ=False):
        """Bars of the first-order and total Sobol indices of each input.

        Parameters
        ----------
        ax : matplotlib Axes, optional
        names : sequence of str, optional
            Input names on the axis (default: the inputs' names, ``w0, ...`` without inputs).
        component : int or tuple
            The output component drawn (``()`` for a scalar output).
        germ : bool
            Draw :meth:`sobol_germ` (dependent inputs, e.g. a fit's ``to_inputs()``).

        Returns
        -------
        matplotlib Axes
        """
        if names is None:
            names = self.inputs.names if self.inputs is not None else None
            names = names or [f"w{k}" for k in range(self.dim)]
        if germ:  # variable k: input k given inputs 0..k-1
            first, total = self.sobol_germ("first"), self.sobol_germ("total")
            names = [f"{n} | {', '.join(names[:k])}" if k else n for k, n in enumerate(names)]
        else:
            first, total = self.first_order(), self.total()
        ax = sobol_bars(first, total, names, ax, component=component)
        ax.set_title("Sobol indices of the PCE" + (" (germ: Cholesky order)" if germ else ""))
        return ax

    # -- evaluation and sampling -------------------------------------------------------
    def evaluate(self, omega):
        """The expansion at germ points.

        Parameters
        ----------
        omega : (n, dim) array_like
            Points in [0, 1]^dim ((n,) when ``dim == 1``).

        Returns
        -------
        (n, *output_shape) ndarray
        """
        pts = self.basis._as_points(omega)
        c = self._flat()
        n = pts.shape[0]
        check_allocation(
            8.0 * n * c.shape[1],
            f"the values of a {c.shape[1]}-value expansion at {n} points",
            "evaluate the points in slices, or only the components you need "
            "(pce.linear_map(A), or PolynomialChaosExpansion(pce.basis, "
            "pce.coefficients[:, idx], pce.inputs))",
        )
        out = np.empty((n, c.shape[1]))
        block = max(1, _EVAL_BLOCK_ENTRIES // self.basis.size)
        for i in range(0, n, block):
            out[i : i + block] = self.basis.evaluate(pts[i : i + block]) @ c
        return out.reshape((n, *self.output_shape))

    def __call__(self, x):
        """The expansion at input points (on the inputs' ranges; the germ if no inputs).

        Parameters
        ----------
        x : (n, dim) array_like

        Returns
        -------
        (n, *output_shape) ndarray
        """
        if self.inputs is None:
            return self.evaluate(x)
        return self.evaluate(self.inputs.to_germ(x))

    def sample(self, n, seed=None, return_inputs=False):
        """Outputs of the surrogate at ``n`` random inputs.

        Parameters
        ----------
        n : int
        seed : None, int or numpy.random.Generator
        return_inputs : bool
            Also return the input points (on their ranges).

        Returns
        -------
        y : (n, *output_shape) ndarray
        x : (n, dim) ndarray, only with ``return_inputs``
        """
        n = check_int("n", n, minimum=1)
        omega = draw_germs(self.basis.germs, n, seed)
        y = self.evaluate(omega)
        if not return_inputs:
            return y
        return y, (omega if self.inputs is None else self.inputs.from_germ(omega))

    def quantile(self, q, n_samples=100_000, seed=0):
        """Output quantiles by sampling the surrogate.

        Parameters
        ----------
        q : float or (r,) array_like
            Probabilities in [0, 1].
        n_samples : int
            Surrogate samples (the quantile's sampling error is about
            :math:`\\sqrt{q(1-q)/n}/f(y_q)`).
        seed : None, int or Generator

        Returns
        -------
        ndarray of shape ``output_shape`` (scalar ``q``) or ``(r, *output_shape)``
        """
        q = as_finite_array("q", q)
        if np.any((q < 0) | (q > 1)):
            raise ValueError(f"`q` must lie in [0, 1], got {q}")
        n_samples = check_int("n_samples", n_samples, minimum=1)
        m = int(np.prod(self.output_shape, dtype=int))
        check_allocation(
            8.0 * (2 * n_samples + q.size) * m,
            f"quantiles of a {m}-value expansion from {n_samples} samples (the samples and "
            "the sorted copy)",
            "pass fewer `n_samples`, or take the quantiles of the components you need "
            "(PolynomialChaosExpansion(pce.basis, pce.coefficients[:, idx], pce.inputs))",
        )
        return np.quantile(self.sample(n_samples, seed), q, axis=0)

    def density(self, component=(), n_samples=20_000, seed=0, bw_method=None):
        """Kernel density estimate of one output component, from surrogate samples.

        Parameters
        ----------
        component : int or tuple
            Index into ``output_shape`` (``()`` for a scalar output).
        n_samples : int
        seed : None, int or Generator
        bw_method : passed to ``scipy.stats.gaussian_kde``

        Returns
        -------
        scipy.stats.gaussian_kde
            Call it (or its ``pdf``) on output values.
        """
        from scipy.stats import gaussian_kde

        y = self.sample(n_samples, seed)
        idx = (component,) if isinstance(component, numbers.Integral) else tuple(component)
        try:
            yc = y[(slice(None), *idx)]
        except IndexError as e:
            raise ValueError(
                f"`component` {component!r} does not index output shape {self.output_shape}"
            ) from e
        if yc.ndim != 1:
            raise ValueError(
                f"`component` must select one output of shape {self.output_shape}, got {component!r}"
            )
        if np.ptp(yc) == 0:
            raise ValueError(f"output component {component!r} is constant; it has no density")
        return gaussian_kde(yc, bw_method=bw_method)

    # -- chaospy interop ---------------------------------------------------------------
    def to_chaospy(self):
        """The expansion as a numpoly polynomial, the type chaospy's expansions use.

        The variables ``q0, ..., q{d-1}`` are the inputs on their own ranges (the germ
        when ``inputs`` is ``None``), so ``chaospy.E(poly, inputs.to_chaospy())`` and
        ``chaospy.Sens_m`` work on it, and ``poly(*x.T)`` evaluates it. Inputs must be
        affine images of their germs (independent uniform, normal, gamma or beta); a
        lognormal or other transformed input makes the expansion non-polynomial in it
        (ValueError).

        Returns
        -------
        numpoly.ndpoly of shape ``output_shape``

        Notes
        -----
        numpoly stores monomial coefficients; for orders beyond about 20 they cancel
        catastrophically, so keep such expansions in this class.
        """
        import numpoly

        if self.inputs is not None and not self.inputs.affine:
            raise ValueError(
                "to_chaospy needs inputs that are affine images of their germs (uniform, "
                f"normal, gamma, beta, independent); these are {self.inputs!r}, so the "
                "expansion is not a polynomial in the inputs. Evaluate it with pce(x), or "
                "export it in the germ variables: PolynomialChaosExpansion(pce.basis, "
                "pce.coefficients).to_chaospy()"
            )
        q = numpoly.variable(self.dim)
        if self.dim == 1:
            q = numpoly.polynomial([q])
        p = self.basis.order
        univariate = []
        for d in range(self.dim):
            germ = self.basis.germs[d]
            if germ.family != "legendre":
                m_d = None if self.inputs is None else self.inputs.marginals[d]
                g = q[d] if m_d is None else (q[d] - m_d.loc) / m_d.scale
                ra, rb = germ.recurrence(p + 1)
                sb = np.sqrt(rb)
                P = [numpoly.polynomial(1.0)]
                prev = numpoly.polynomial(0.0)
                for m in range(p):
                    P.append(((g - ra[m]) * P[m] - sb[m] * prev) / sb[m + 1])
                    prev = P[m]
                univariate.append(P)
                continue
            if self.inputs is None:
                a, b = 0.0, 1.0
            elif isinstance(self.inputs, UniformInputs):
                a, b = self.inputs.bounds[d]
            else:
                m_d = self.inputs.marginals[d]
                a, b = m_d.loc, m_d.loc + m_d.scale
            t = 2.0 * (q[d] - a) / (b - a) - 1.0
            P = [numpoly.polynomial(1.0), t]
            for m in range(1, p):
                P.append(((2 * m + 1) * t * P[m] - m * P[m - 1]) / (m + 1))
            univariate.append([np.sqrt(2 * m + 1) * P[m] for m in range(p + 1)])
        terms = []
        for alpha in self.basis.indices:
            term = numpoly.polynomial(1.0)
            for d, a in enumerate(alpha):
                if a:
                    term = term * univariate[d][a]
            terms.append(term)
        scale = np.sqrt(np.asarray(self.basis.norms2))
        psi = numpoly.polynomial(terms) * scale
        c = self._flat()
        poly = numpoly.sum(psi.reshape(-1, 1) * c, axis=0)
        return poly.reshape(self.output_shape)
