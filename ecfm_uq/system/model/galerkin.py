"""The stochastic Galerkin system :math:`R(\\Theta; \\epsilon, \\lambda) = 0`.

.. math::

    R_{i\\ell} = \\sum_{\\text{terms}} (\\ldots)_{i\\ell}
        - \\Gamma_{ij}\\lambda_j\\,\\mathbb E[\\Psi_\\ell],

the paper's Eq. (pce) in general form: linear operators with random coefficients,
polynomial nonlinearities and loads (see :mod:`.terms`), plus constraint forces
:math:`\\Gamma\\lambda` (Eqs. parameterized_bvp_ecfm, random_govern). With no chaos basis
(``P = 1``, :math:`\\Psi_0 = 1`) it is the deterministic discretized system of Sections
3.1, 3.2 and 4, solved by the same code.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..._validation import as_finite_array, as_operator, check_int, describe
from ...memory import check_covariance
from .nonlinear_term import NonlinearTerm
from .operator import GalerkinOperator, _LinearPart, _QuadraticLinearization
from .structure import SystemStructure, triple_product_pairs
from .terms import LinearTerm, LoadTerm, QuadraticTerm


def _check_parameters(terms, n_eps):
    """Every coefficient must read parameter indices below ``n_eps``."""
    for term in terms:
        coef = getattr(term, "coef", None)
        indices = getattr(coef, "indices", None)
        if not indices:
            continue
        bad = [m for m in indices if m >= n_eps]
        if bad:
            raise ValueError(
                f"term {term.name!r}: coefficient {coef.label} uses parameter index "
                f"{bad[0]} but the system has n_eps={n_eps} parameters "
                f"(indices 0..{n_eps - 1}); raise `n_eps` or fix the index"
            )


def _term_size(term):
    """The state size a term fixes (``None``: it does not)."""
    if isinstance(term, LinearTerm):
        return term.K.shape[0]
    if isinstance(term, QuadraticTerm):
        return term.form.size
    if isinstance(term, NonlinearTerm):
        return term.size
    return None


class GalerkinSystem:
    """A discretized, parameterized (stochastic) model.

    Parameters
    ----------
    terms : sequence of LinearTerm, QuadraticTerm, NonlinearTerm, LoadTerm
        Residual contributions; they are summed. The system keeps copies bound to its
        chaos basis (``system.terms``, a tuple); the terms passed in are left unbound, so
        they can build systems of other sizes ``P``.
    n_eps : int
        Number of model parameters :math:`\\epsilon`.
    basis : ChaosBasis, optional
        Stochastic basis; ``None`` for a deterministic system (``P = 1``).
    Gamma : (N, C) array_like or scipy.sparse matrix, optional
        Constraint-force vectors :math:`\\Gamma_{ij} = \\int f_i\\Gamma(x - x_j)`.
    M : (N, N) array_like or scipy.sparse matrix, optional
        Mass matrix for time-dependent systems :math:`M\\dot\\theta + R = 0`.
    name : str

    Notes
    -----
    The system is immutable: its terms, basis, operators and expectation tensors are
    fixed at construction, and what solvers derive from them is computed once in
    ``system.structure`` (:class:`~.structure.SystemStructure`).

    Shapes: :math:`\\Theta` is ``(N, P)``, flattened row-major (index ``i * P + k``) in
    Jacobians; :math:`\\epsilon` is ``(n_eps,)``; :math:`\\lambda` is ``(C,)``.
    """

    def __init__(self, terms, n_eps, basis=None, Gamma=None, M=None, name="system"):
        terms = tuple(terms)
        if not terms:
            raise ValueError("`terms` must contain at least one term")
        for term in terms:
            if not isinstance(term, LinearTerm | QuadraticTerm | NonlinearTerm | LoadTerm):
                raise TypeError(
                    f"`terms` holds an unsupported {describe(term)}; use LinearTerm, "
                    "QuadraticTerm, NonlinearTerm or LoadTerm (e.g. LoadTerm.constant(F))"
                )
        self.n_eps = check_int("n_eps", n_eps, minimum=0)
        self.basis = basis
        if basis is None:
            self.E1 = np.ones(1)
            self.E2 = np.ones((1, 1))
            self.E3 = np.ones((1, 1, 1))
        else:
            from ...chaos import expectation_tensor

            self.E1 = np.array(expectation_tensor(basis, 1), dtype=float)
            self.E2 = np.array(expectation_tensor(basis, 2), dtype=float)
            needs3 = any(isinstance(t, QuadraticTerm) for t in terms)
            self.E3 = np.array(expectation_tensor(basis, 3), dtype=float) if needs3 else None
        self.P = self.E1.size
        for E in (self.E1, self.E2, self.E3):
            if E is not None:
                E.setflags(write=False)
        sizes = {t.K.shape[0] for t in terms if isinstance(t, LinearTerm)}
        sizes |= {t.form.size for t in terms if isinstance(t, QuadraticTerm)}
        sizes |= {t.size for t in terms if isinstance(t, NonlinearTerm) and t.size is not None}
        if not sizes:
            raise ValueError(
                "`terms` has no LinearTerm or QuadraticTerm, so the state size N is unknown; "
                "add the model's operator (e.g. LinearTerm(K)) or pass NonlinearTerm(size=N)"
            )
        if len(sizes) != 1:
            named = sorted(
                f"{t.name!r}: {_term_size(t)}" for t in terms if _term_size(t) is not None
            )
            raise ValueError(
                f"terms disagree on the state size N ({', '.join(named)}); "
                "build every operator on the same discretization"
            )
        self.N = sizes.pop()
        _check_parameters(terms, self.n_eps)
        # the system keeps bound copies: the caller's terms stay unbound and reusable in a
        # system of another P
        pairs = None if self.E3 is None else triple_product_pairs(self.E3)
        bound = []
        for term in terms:
            if isinstance(term, LinearTerm):
                bound.append(term.bind(self.E2))
            elif isinstance(term, QuadraticTerm):
                bound.append(term.bind(self.E3, pairs))
            elif isinstance(term, NonlinearTerm):
                bound.append(term.bind(basis, self.N, self.n_eps))
            else:
                term.check_sizes(self.N, self.n_eps)
                bound.append(term.bind(self.E1, self.N))
        self.terms = tuple(bound)
        self.Gamma = None if Gamma is None else as_operator("Gamma", Gamma)
        if self.Gamma is not None and self.Gamma.shape[0] != self.N:
            raise ValueError(f"`Gamma` must have {self.N} rows (N), got {self.Gamma.shape}")
        self.M = None if M is None else as_operator("M", M, shape=(self.N, self.N))
        self.name = name
        self.structure = SystemStructure(self, pairs)
        self._frozen = True

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(
                f"GalerkinSystem is immutable: cannot set {name!r}; build a new system "
                "from the terms (GalerkinSystem(terms, n_eps, ...))"
            )
        object.__setattr__(self, name, value)

    # -- sizes -------------------------------------------------------------------------
    @property
    def n_forces(self):
        """Number of constraint forces C (0 without Gamma)."""
        return 0 if self.Gamma is None else self.Gamma.shape[1]

    @property
    def shape(self):
        """State shape (N, P)."""
        return (self.N, self.P)

    def zeros(self):
        """A zero state of shape (N, P)."""
        return np.zeros(self.shape)

    def check_eps(self, eps):
        """Validate ``eps`` as a finite (n_eps,) vector."""
        eps = np.atleast_1d(as_finite_array("eps", eps))  # strings, ragged lists refused
        return as_finite_array("eps", eps, shape=(self.n_eps,))

    def check_initial_state(self, Theta0):
        """Validate an initial state: (N, P) chaos coefficients, or (N,) a deterministic
        state (its mean coefficients, the rest zero); returned as (N, P)."""
        N, P = self.shape
        Theta0 = as_finite_array("Theta0", Theta0)
        if Theta0.shape == (N,):
            Theta0 = np.outer(Theta0, np.eye(P)[0])
        if Theta0.shape != (N, P):
            raise ValueError(f"`Theta0` must have shape {(N, P)} or {(N,)}, got {Theta0.shape}")
        return Theta0

    def check_lam(self, lam):
        """Validate ``lam`` (None means zero forces)."""
        if lam is None:
            return np.zeros(self.n_forces)
        if self.Gamma is None:
            raise ValueError("`lam` given but the system has no constraint forces (Gamma=None)")
        lam = np.atleast_1d(as_finite_array("lam", lam))
        return as_finite_array("lam", lam, shape=(self.n_forces,))

    # -- residual and derivatives ------------------------------------------------------
    def residual(self, Theta, eps, lam=None, t=None):
        """:math:`R(\\Theta; \\epsilon, \\lambda)` of shape (N, P)."""
        if np.shape(Theta) != self.shape:  # cheap: a shape, no copy
            raise ValueError(
                f"`Theta` must have shape (N, P) = {self.shape}, got {np.shape(Theta)}; "
                "a deterministic state is (N, 1), use system.zeros() for a template"
            )
        R = np.zeros(self.shape)
        for term in self.terms:
            R += term.apply(Theta, eps, t)
        if lam is not None:
            if self.Gamma is None:
                if np.any(np.asarray(lam) != 0):
                    raise ValueError("`lam` given but the system has no constraint forces (Gamma)")
            else:
                R -= np.outer(self.Gamma @ np.asarray(lam, dtype=float), self.E1)
        return R

    def residual_scale(self, Theta, eps, lam=None, t=None):
        """The magnitude of the terms that :meth:`residual` adds up, a float.

        :math:`\\sum \\| |c|\\,|K||\\Theta||G| \\| + \\| |c|\\,|A|:|\\Theta||\\Theta| \\|
        + \\|F\\| + \\|\\Gamma\\lambda\\|`: floating point cannot evaluate :math:`R` (nor
        drive it) below a small multiple of the unit round-off times this, whatever the
        model's units (:func:`..solve.plan.residual_floor`).
        """
        s = 0.0
        for term in self.terms:
            if isinstance(term, LinearTerm | QuadraticTerm):
                c = abs(float(term.coef.value(eps)))
                s += c * float(np.linalg.norm(term.magnitude(Theta)))
            elif isinstance(term, NonlinearTerm):
                s += float(np.linalg.norm(term.magnitude(Theta, eps)))
            else:
                s += float(np.linalg.norm(term.apply(Theta, eps, t)))
        if lam is not None and self.Gamma is not None:
            s += float(np.linalg.norm(self.Gamma @ np.asarray(lam, dtype=float)))
        return s

    def mass_scale(self, X):
        """:math:`\\| |M|\\,|X|\\,|\\mathbb E[\\Psi\\Psi^T]| \\|` for ``X`` (N, P): the round-off
        scale of the mass term (see :meth:`residual_scale`)."""
        absM = abs(self.M)
        return float(np.linalg.norm(np.asarray(absM @ np.abs(X)) @ np.abs(self.E2)))

    def jacobian_operator(self, Theta, eps, t=None, dt=None):
        """The Jacobian at ``Theta`` as a structured :class:`~.operator.GalerkinOperator`.

        Nothing is assembled: the operator applies itself matrix-free and assembles dense,
        sparse or its mean block on request (the solver layer decides which). ``dt`` adds
        the backward-Euler mass term :math:`M\\otimes\\mathbb E[\\Psi\\Psi^T]/\\Delta t`. For
        a linear system the same object is returned for the same ``(eps, dt)``, so a
        solver can reuse its factorization.
        """
        if self.is_linear:
            key = (np.asarray(eps, dtype=float).tobytes(), dt)
            op = self.structure.cached_operator(key)
            if op is not None:
                return op
        parts = []
        for term in self.terms:
            if isinstance(term, LinearTerm):
                parts.append(_LinearPart(term, term.coef.value(eps)))
            elif isinstance(term, QuadraticTerm):
                parts.append(_QuadraticLinearization(term, Theta, term.coef.value(eps)))
            elif isinstance(term, NonlinearTerm):
                parts.append(term.linearize(Theta, eps))
        op = GalerkinOperator(self, parts, dt=dt)
        if self.is_linear:
            self.structure.store_operator(key, op)
        return op

    def jacobian(self, Theta, eps, t=None):
        """:math:`\\partial\\,\\mathrm{vec}R / \\partial\\,\\mathrm{vec}\\Theta`, dense (NP, NP).

        Refused (:class:`~ecfm_uq.errors.MemoryBudgetError`) when it would not fit the
        memory budget; use :meth:`jacobian_operator` for large systems.
        """
        return self.jacobian_operator(Theta, eps, t).to_dense()

    @property
    def is_linear(self):
        """True when no term is quadratic (or a :class:`NonlinearTerm`) in the state."""
        return self.structure.is_linear

    @property
    def sparse_input(self):
        """True when any spatial operator, ``M`` or ``Gamma`` is ``scipy.sparse``."""
        return self.structure.sparse_input

    def eps_jacobian(self, Theta, eps, t=None):
        """:math:`\\partial\\,\\mathrm{vec}R / \\partial\\epsilon`, shape (NP, n_eps)."""
        D = np.zeros((self.N * self.P, self.n_eps))
        for term in self.terms:
            if _eps_free(term):
                # its columns are zeros: a sum from +0 never holds -0, so adding them
                # changes no bit (a term's Python overhead, four times at every point of
                # the random-force ECFM's second derivatives)
                continue
            D += term.eps_jacobian(Theta, eps, t)
        return D

    def eps_vjp(self, Theta, eps, mu, t=None):
        """:math:`(\\partial\\,\\mathrm{vec}R/\\partial\\epsilon)^T\\mu`, (n_eps,), for adjoints.

        Term by term, without forming the (NP, n_eps) matrix (which for a large system
        and many parameters costs more than the adjoint solve itself).
        """
        mu = np.reshape(mu, self.shape)
        g = np.zeros(self.n_eps)
        for term in self.terms:
            g += term.eps_vjp(Theta, eps, mu, t)
        return g

    def lam_jacobian(self):
        """:math:`\\partial\\,\\mathrm{vec}R / \\partial\\lambda = -\\Gamma\\otimes\\mathbb E[\\Psi]`, (NP, C)."""
        if self.Gamma is None:
            return np.zeros((self.N * self.P, 0))
        Gamma = self.Gamma.toarray() if sp.issparse(self.Gamma) else self.Gamma
        return -(Gamma[:, None, :] * self.E1[None, :, None]).reshape(self.N * self.P, -1)

    def constraint_jacobian(self, M_obs):
        """:math:`\\mathcal M \\otimes \\mathbb E[\\Psi]^T`, (C, NP): the data constraint's Jacobian.

        Sparse when ``M_obs`` is sparse.
        """
        if sp.issparse(M_obs):
            return sp.kron(M_obs, sp.csr_matrix(self.E1[None, :]), format="csr")
        return np.kron(M_obs, self.E1[None, :])

    def mass_matrix(self, sparse=False):
        """:math:`M \\otimes \\mathbb E[\\Psi_k\\Psi_\\ell]`, shape (NP, NP) (CSR if ``sparse``)."""
        if self.M is None:
            raise ValueError(f"system {self.name!r} has no mass matrix; pass M= for time stepping")
        return self.structure.mass_matrix(sparse)

    def apply_mass(self, X, transpose=False):
        """:math:`M X \\mathbb E[\\Psi\\Psi^T]` (or :math:`M^T X \\ldots`) for ``X`` (N, P), matrix-free."""
        if self.M is None:
            raise ValueError(f"system {self.name!r} has no mass matrix; pass M= for time stepping")
        M = self.M.T if transpose else self.M
        return np.asarray(M @ X) @ (self.E2.T if transpose else self.E2)

    def mass_is_symmetric(self):
        """Whether ``M`` is symmetric."""
        return self.structure.mass_symmetric

    # -- structure ---------------------------------------------------------------------
    def decoupling(self):
        """Common eigenbasis of the stochastic couplings, if the system allows one.

        For a linear system whose couplings :math:`G_q = \\mathbb E[g_q\\Psi\\Psi^T]` are
        simultaneously diagonalizable, :math:`G_q = Q D_q Q^T` (e.g. every operator
        affine in one germ: :math:`\\mathbb E[\\omega\\Psi\\Psi^T]` is the Jacobi matrix,
        whose eigenvectors are the Gauss nodes), the block system splits into ``P``
        independent ``N x N`` systems :math:`(\\sum_q c_q d_{qp} K_q)\\hat\\theta_p = \\hat b_p`
        with :math:`\\Theta = \\hat\\Theta Q^T`.

        Returns
        -------
        (Q (P, P), D (n_linear, P)) or None
            ``None`` for nonlinear systems, ``P = 1``, or couplings without a common
            eigenbasis (the dense block solve is used then).
        """
        return self.structure.decoupling

    def gauss_nodes(self):
        """The one-germ chaos basis at its ``P``-node Gauss rule (cached), or ``None``.

        ``None`` for ``P = 1`` or a basis with several germs. The node-wise
        preconditioner and the compiled stochastic march use it
        (:class:`ecfm_uq.chaos.GaussNodes`).
        """
        return self.structure.gauss_nodes

    # -- statistics --------------------------------------------------------------------
    def mean(self, Theta):
        """:math:`\\mathbb E[\\theta] = \\Theta\\,\\mathbb E[\\Psi]`, shape (N,)."""
        return Theta @ self.E1

    def covariance(self, Theta):
        """:math:`\\mathrm{Cov}[\\theta] = \\Theta\\,\\mathbb E[\\Psi\\Psi^T]\\,\\Theta^T - \\mu\\mu^T`, (N, N).

        Raises
        ------
        MemoryBudgetError
            When the (N, N) matrix does not fit the memory budget; the pointwise
            :meth:`variance` needs only (N,).
        """
        check_covariance(np.shape(Theta)[0], "covariance of the field", "system.variance(Theta)")
        mu = self.mean(Theta)
        return Theta @ self.E2 @ Theta.T - np.outer(mu, mu)

    def variance(self, Theta):
        """Pointwise :math:`\\mathrm{Var}[\\theta_i]`, shape (N,), without the (N, N) covariance."""
        mu = self.mean(Theta)
        return np.einsum("ik,kl,il->i", Theta, self.E2, Theta) - mu**2

    def __repr__(self):
        return f"GalerkinSystem({self.name!r}, N={self.N}, P={self.P}, n_eps={self.n_eps}, C={self.n_forces})"


def _eps_free(term):
    """Whether a term does not depend on eps: a linear or quadratic term with a constant
    coefficient, a load without a derivative."""
    if isinstance(term, LinearTerm | QuadraticTerm):
        return term.coef.is_constant
    return isinstance(term, LoadTerm) and term.dF is None
