"""Terms of the stochastic Galerkin residual :math:`R(\\Theta; \\epsilon, \\lambda)`.

The state is :math:`\\theta_i(\\omega) = \\Theta_{ik}\\Psi_k(\\omega)` with
:math:`\\Theta` of shape ``(N, P)`` (paper Section 3.3, Eq. pce); ``P = 1`` with
:math:`\\Psi_0 = 1` is the deterministic problem of Sections 3.1, 3.2 and 4. Projecting a
term of the spatial residual onto :math:`\\Psi_\\ell` gives

* linear, :math:`c(\\epsilon)\\,K\\,\\theta\\,g(\\omega)` :
  :math:`c(\\epsilon) K_{ij}\\Theta_{jk}\\,\\mathbb E[g\\Psi_k\\Psi_\\ell]`,
* quadratic, :math:`c(\\epsilon)\\,A:\\theta\\otimes\\theta` :
  :math:`c(\\epsilon) A_{ijk}\\Theta_{jb}\\Theta_{kc}\\,\\mathbb E[\\Psi_b\\Psi_c\\Psi_\\ell]`,
* load, :math:`-F(\\epsilon, t)` : :math:`-F_i\\,\\mathbb E[\\Psi_\\ell]`.

Each term returns its contribution, its Jacobian in :math:`\\mathrm{vec}(\\Theta)`
(row-major, flat index ``i * P + k``) and its derivative in :math:`\\epsilon`; the
system (:mod:`.galerkin`) only adds them up.
"""

from __future__ import annotations

import copy
import math
import numbers

import numpy as np
import scipy.sparse as sp

from ..._validation import as_finite_array, as_operator, check_int, check_real, is_sparse
from ..._validation import describe as _describe


class Coefficient:
    """Scalar coefficient :math:`c(\\epsilon)` with its gradient.

    Parameters
    ----------
    value : callable
        ``value(eps) -> float``.
    grad : callable
        ``grad(eps) -> (n_eps,)``.
    indices : sequence of int, optional
        The parameter indices :math:`m` the coefficient reads; the system checks them
        against its ``n_eps`` at construction. ``None`` means unknown (a user callable).
    label : str, optional
        Shown in error messages, e.g. ``"10**(-eps[0])"``.

    Notes
    -----
    Evaluation is guarded: an overflow, NaN or inf in ``value`` or ``grad`` raises
    :class:`~ecfm_uq.errors.ModelEvaluationError` naming the coefficient and ``eps``,
    which the solvers report as a failed solve instead of a raw numpy/Python error.
    """

    def __init__(self, value, grad, indices=None, label="coefficient"):
        if not callable(value):
            raise TypeError(f"`value` must be callable value(eps), got {_describe(value)}")
        if not callable(grad):
            raise TypeError(f"`grad` must be callable grad(eps), got {_describe(grad)}")
        self._value = value
        self._grad = grad
        self.indices = None if indices is None else tuple(int(m) for m in indices)
        self.label = label
        self.is_constant = False  # True from Coefficient.constant: grad(eps) is zero

    def value(self, eps):
        """:math:`c(\\epsilon)` as a finite float (ModelEvaluationError otherwise)."""
        try:
            with np.errstate(over="raise", invalid="raise"):
                c = call_user(self._value, f"coefficient {self.label}", "value(eps)", eps)
        except (OverflowError, FloatingPointError, ZeroDivisionError) as e:
            raise _evaluation_error(self.label, eps, e) from e
        if isinstance(c, float):  # the usual case, numpy's float64 included: no array
            finite = math.isfinite(c)
        else:
            try:
                finite = np.all(np.isfinite(c))
            except TypeError:
                finite = True  # not numeric: let the caller's arithmetic say so
        if not finite:
            raise _evaluation_error(self.label, eps, f"value {c}")
        return c

    def grad(self, eps):
        """:math:`\\nabla_\\epsilon c`, shape ``(n_eps,)``, finite (ModelEvaluationError otherwise)."""
        try:
            with np.errstate(over="raise", invalid="raise"):
                g = call_user(self._grad, f"coefficient {self.label}", "grad(eps)", eps)
        except (OverflowError, FloatingPointError, ZeroDivisionError) as e:
            raise _evaluation_error(self.label, eps, e) from e
        finite = np.isfinite(g)
        if not (finite.all() if isinstance(finite, np.ndarray) else finite):
            raise _evaluation_error(self.label, eps, "non-finite gradient")
        return g

    @classmethod
    def constant(cls, c):
        """:math:`c(\\epsilon) = c`."""
        c = check_real("c", c)
        coef = cls(lambda eps: c, lambda eps: np.zeros(len(eps)), indices=(), label=f"{c:g}")
        coef.is_constant = True
        return coef

    @classmethod
    def parameter(cls, index, scale=1.0):
        """:math:`c(\\epsilon) = s\\,\\epsilon_m` (e.g. the source scale :math:`\\epsilon_2`)."""
        m = check_int("index", index, minimum=0)
        scale = check_real("scale", scale)

        def grad(eps):
            g = np.zeros(len(eps))
            g[m] = scale
            return g

        return cls(
            lambda eps: scale * float(eps[m]), grad, indices=(m,), label=f"{scale:g}*eps[{m}]"
        )

    @classmethod
    def power10(cls, index, sign=-1.0, scale=1.0):
        """:math:`c(\\epsilon) = s\\,10^{\\pm\\epsilon_m}` (the viscosity :math:`10^{-\\epsilon_1}`)."""
        m = check_int("index", index, minimum=0)
        sign = check_real("sign", sign)
        scale = check_real("scale", scale)

        def value(eps):
            return scale * 10.0 ** (sign * float(eps[m]))

        def grad(eps):
            g = np.zeros(len(eps))
            g[m] = np.log(10.0) * sign * value(eps)
            return g

        return cls(value, grad, indices=(m,), label=f"{scale:g}*10**({sign:g}*eps[{m}])")


def call_user(fn, what, signature, *args):
    """``fn(*args)``, a user's callback, with a signature mistake named: a TypeError or
    IndexError raised by the call (a callback taking other arguments, or reading more
    parameters than the model has) comes back as the same type naming the callback
    (``what``), the signature it must have and the arguments it was called with."""
    try:
        return fn(*args)
    except (TypeError, IndexError) as e:
        shown = ", ".join(
            f"eps={np.asarray(a).tolist()}" if k == 0 else f"{a!r}" for k, a in enumerate(args)
        )
        raise type(e)(
            f"{what} raised {type(e).__name__} when called as {signature} with {shown}: "
            f"{e}; it must take exactly those arguments and use only the "
            f"{np.size(args[0])} parameters eps[0..{np.size(args[0]) - 1}]"
        ) from e


def _evaluation_error(label, eps, cause):
    from ...errors import ModelEvaluationError

    if isinstance(cause, OverflowError):
        cause = "overflow"
    elif isinstance(cause, FloatingPointError | ZeroDivisionError):
        cause = f"floating-point error: {cause}"
    return ModelEvaluationError(
        f"coefficient {label} cannot be evaluated at eps={np.asarray(eps).tolist()} "
        f"({cause}); keep the parameters in a physical range (e.g. `bounds`)"
    )


def as_coefficient(c):
    """Accept a number or a :class:`Coefficient`."""
    if isinstance(c, Coefficient):
        return c
    if isinstance(c, numbers.Real) and not isinstance(c, bool):
        return Coefficient.constant(c)
    raise TypeError(
        f"`coef` must be a number or a Coefficient, got {_describe(c)}; "
        "wrap functions of eps as Coefficient(value, grad)"
    )


def right_multiply(X, G, G_sparse=None):
    """:math:`X G` for ``X`` of shape (N, P), with the sparse copy of ``G`` when given.

    The stochastic couplings of affine random inputs have a few nonzeros a row, so for
    large ``P`` the product costs ``O(N nnz(G))`` instead of ``O(N P^2)``.
    """
    if G_sparse is None:
        return X @ G
    return np.asarray(G_sparse.T @ X.T).T


# entries of a coupling below this fraction of its largest are the round-off of integrals
# that vanish exactly (e.g. E[xi_q Psi_a Psi_b] of multi-indices differing in two germs)
_COUPLING_ROUNDOFF = 1e-13


def _without_roundoff(G):
    """``G`` with the round-off of integrals that vanish exactly set to zero.

    A coupling computed by quadrature carries round-off where its integrals vanish; kept,
    those entries would make every coupling dense (an affine germ's 35 x 35 coupling at
    order 3: 30 entries, ~1 200 at 1e-17) in the matrix-free products and in the assembled
    sparse Jacobian alike (a change at the round-off level of the largest entry).
    """
    big = np.abs(G) > _COUPLING_ROUNDOFF * np.abs(G).max(initial=0.0)
    return G if big.all() else np.where(big, G, 0.0)


def _sparse_coupling(G):
    """CSR copy of a coupling worth multiplying sparsely, else ``None``."""
    P = G.shape[0]
    if P < 10 or np.count_nonzero(G) > 0.25 * P * P:
        return None
    return sp.csr_matrix(G)


class LinearTerm:
    """:math:`c(\\epsilon)\\,K\\,\\Theta\\,G` with a stochastic coupling :math:`G`.

    Parameters
    ----------
    K : (N, N) ndarray or scipy.sparse matrix
        Spatial operator. A sparse ``K`` (e.g. from scikit-fem) is kept sparse: the
        residual, the Jacobian action and the solvers never form an ``N x N`` dense array.
    coef : float or Coefficient
        :math:`c(\\epsilon)`.
    G : (P, P) array_like, optional
        :math:`G_{k\\ell} = \\mathbb E[g(\\omega)\\Psi_k\\Psi_\\ell]` (symmetric). ``None``
        means :math:`g = 1`, i.e. :math:`G = \\mathbb E[\\Psi_k\\Psi_\\ell]`, supplied by the
        system.

    Notes
    -----
    The term only describes itself (``coef``, ``K``, ``G``); whether its Jacobian
    :math:`c\\,K \\otimes G^T` is assembled dense, assembled sparse or applied matrix-free
    is decided by the solver layer (:mod:`.operator`, :mod:`..solve.linear`).
    """

    def __init__(self, K, coef=1.0, G=None, name="linear"):
        self.K = as_operator("K", K, square=True)
        self.coef = as_coefficient(coef)
        self.G = None if G is None else as_finite_array("G", G, ndim=2)
        self._G_given = self.G
        self.name = name

    @property
    def sparse(self):
        """True when ``K`` is a ``scipy.sparse`` matrix."""
        return is_sparse(self.K)

    def bind(self, E2):
        """A copy bound to a system with Gram matrix ``E2`` (P, P); ``self`` is unchanged.

        The copy's ``G`` is the given coupling, or ``E2`` when none was given, without its
        round-off entries (:func:`_without_roundoff`).
        """
        G = E2 if self._G_given is None else self._G_given
        if G.shape != E2.shape:
            raise ValueError(f"term {self.name!r}: `G` has shape {G.shape}, expected {E2.shape}")
        bound = copy.copy(self)
        bound.G = _without_roundoff(G)
        bound._G_sparse = _sparse_coupling(bound.G)
        bound._kron = {}
        bound._abs = None
        bound._transposed = None  # (K^T, G_sparse^T) built once, for adjoint solves
        bound.__dict__.pop("_symmetric", None)
        return bound

    def magnitude(self, X):
        """:math:`|K|\\,|X|\\,|G|` (N, P), without the coefficient: the scale of the
        round-off in :meth:`action` (see :func:`..solve.plan.residual_floor`)."""
        if self._abs is None:
            self._abs = (abs(self.K), np.abs(self.G))
        absK, absG = self._abs
        return np.asarray(absK @ np.abs(X)) @ absG

    def action(self, X):
        """:math:`K X G` (without the coefficient) for ``X`` of shape (N, P)."""
        return right_multiply(np.asarray(self.K @ X), self.G, self._G_sparse)

    def action_transpose(self, Y):
        """:math:`K^T Y G^T` for ``Y`` of shape (N, P): the transposed Jacobian's action."""
        if getattr(self, "_transposed", None) is None:  # one transpose, not one per product
            KT = self.K.T.tocsr() if is_sparse(self.K) else self.K.T
            GT = None if self._G_sparse is None else self._G_sparse.T.tocsr()
            self._transposed = (KT, GT)
        KT, GT = self._transposed
        return right_multiply(np.asarray(KT @ Y), self.G.T, GT)

    def kron(self, kind):
        """:math:`K \\otimes G^T` as a dense (``kind="dense"``) or CSR (``"sparse"``) matrix.

        Cached: the operator is fixed, only the coefficient varies with :math:`\\epsilon`.
        """
        if kind not in self._kron:
            if kind == "dense":
                K = self.K.toarray() if self.sparse else self.K
                self._kron[kind] = np.kron(K, self.G.T)
            else:
                self._kron[kind] = sp.kron(self.K, sp.csr_matrix(self.G.T), format="csr")
        return self._kron[kind]

    def is_symmetric(self):
        """Whether :math:`K` and :math:`G` are symmetric (to 1e-12 of their scale)."""
        if not hasattr(self, "_symmetric"):
            self._symmetric = _symmetric(self.K) and _symmetric(self.G)
        return self._symmetric

    def apply(self, Theta, eps, t=None):
        return self.coef.value(eps) * self.action(Theta)

    def eps_jacobian(self, Theta, eps, t=None):
        return np.outer(self.action(Theta).ravel(), self.coef.grad(eps))

    def eps_vjp(self, Theta, eps, mu, t=None):
        """:math:`(\\partial R/\\partial\\epsilon)^T\\mu` without the (NP, n_eps) matrix."""
        return self.coef.grad(eps) * float(np.vdot(self.action(Theta), mu))


def _symmetric(A):
    if is_sparse(A):
        D = (A - A.T).tocsr()
        err = abs(D).max() if D.nnz else 0.0
    else:
        err = np.abs(A - A.T).max()
    return bool(err <= 1e-12 * max(abs(A).max(), 1e-300))


class DenseQuadraticForm:
    """Quadratic form :math:`q(x, y)_i = A_{ijk} x_j y_k` from a dense tensor.

    Any object with ``apply(X, Y)`` (column-wise, ``(N, m)`` arrays) and
    ``matrix(x)`` (the ``(N, N)`` matrix :math:`S(x)_{ij} = (A_{ijk} + A_{ikj}) x_k`) can
    replace it, e.g. a Kronecker-factored form for 2-D bases.
    """

    def __init__(self, A):
        self.A = as_finite_array("A", A, ndim=3)
        n = self.A.shape[0]
        if self.A.shape != (n, n, n):
            raise ValueError(f"`A` must have shape (N, N, N), got {self.A.shape}")
        self._Asym = self.A + self.A.transpose(0, 2, 1)

    @property
    def size(self):
        return self.A.shape[0]

    def apply(self, X, Y):
        return np.einsum("ijk,jm,km->im", self.A, X, Y, optimize=True)

    def matrix(self, x):
        return self._Asym @ x


class QuadraticTerm:
    """:math:`c(\\epsilon)\\,A:\\theta\\otimes\\theta` projected with :math:`\\mathbb E[\\Psi_b\\Psi_c\\Psi_\\ell]`.

    Parameters
    ----------
    form : DenseQuadraticForm or (N, N, N) array_like
        The quadratic form :math:`A`.
    coef : float or Coefficient
    """

    def __init__(self, form, coef=1.0, name="quadratic"):
        if hasattr(form, "matrix"):
            missing = [a for a in ("apply", "matrix", "size") if not hasattr(form, a)]
            if missing:
                raise TypeError(
                    f"`form` {type(form).__name__} lacks {missing}; pass an (N, N, N) array or "
                    "an object with apply(X, Y), matrix(x) and size (see DenseQuadraticForm)"
                )
            self.form = form
        else:
            self.form = DenseQuadraticForm(form)
        self.coef = as_coefficient(coef)
        self.name = name

    def bind(self, E3, pairs):
        """A copy bound to a system with triple products ``E3`` (P, P, P); ``self`` is unchanged.

        ``pairs``: the ``(bs, cs, W)`` of :func:`.structure.triple_product_pairs`, computed
        once by the system for all its quadratic terms; :math:`q(\\Theta_b, \\Theta_c)` is
        evaluated once per structurally nonzero pair.
        """
        bound = copy.copy(self)
        bound._E3 = E3
        bound._P = E3.shape[0]
        bound._bs, bound._cs, bound._W = pairs
        return bound

    @property
    def E3(self):
        """:math:`\\mathbb E[\\Psi_a\\Psi_b\\Psi_c]` (P, P, P) of the system the term is bound to."""
        try:
            return self._E3
        except AttributeError:
            raise ValueError(
                f"term {self.name!r} is not bound to a system; use the copy in system.terms"
            ) from None

    def _abs_form(self):
        """The form with :math:`|A|` (a dense form), else the form itself (an estimate)."""
        if getattr(self, "_form_abs", None) is None:
            A = getattr(self.form, "A", None)
            self._form_abs = self.form if A is None else DenseQuadraticForm(np.abs(A))
        return self._form_abs

    def magnitude(self, Theta, X=None):
        """The round-off scale of the projected form (no coefficient), (N, P).

        :math:`|A|:|\\Theta||\\Theta|` projected with :math:`|\\mathbb E[\\Psi\\Psi\\Psi]|`; with
        ``X``, the same for the Jacobian action :meth:`linear_action` along ``X``.
        """
        form, T = self._abs_form(), np.abs(Theta)
        Y = T if X is None else np.abs(X)
        if self._P == 1:
            out = np.abs(form.apply(Y, T))
            return out if X is None else out + np.abs(form.apply(T, Y))
        bs, cs, W = self._bs, self._cs, np.abs(self._W)
        out = np.abs(form.apply(Y[:, bs], T[:, cs]))
        if X is not None:
            out = out + np.abs(form.apply(T[:, bs], Y[:, cs]))
        return out @ W

    def _raw(self, Theta):
        if self._P == 1:
            return self.form.apply(Theta, Theta)
        return self.form.apply(Theta[:, self._bs], Theta[:, self._cs]) @ self._W

    def apply(self, Theta, eps, t=None):
        return self.coef.value(eps) * self._raw(Theta)

    def linear_action(self, Theta, X):
        """Directional derivative of the projected form at ``Theta`` along ``X`` (no coefficient).

        The Jacobian action :math:`q(X_b, \\Theta_c) + q(\\Theta_b, X_c)` projected with
        :math:`\\mathbb E[\\Psi_b\\Psi_c\\Psi_\\ell]`, without forming the Jacobian.
        """
        if self._P == 1:
            return self.form.apply(X, Theta) + self.form.apply(Theta, X)
        bs, cs = self._bs, self._cs
        return (
            self.form.apply(X[:, bs], Theta[:, cs]) + self.form.apply(Theta[:, bs], X[:, cs])
        ) @ self._W

    def coordinates(self):
        """Nonzeros of the tensor :math:`A_{ijk}` as ``(i, j, k, value)`` arrays (cached).

        Built from the form by contracting unit vectors (``N^2`` columns), so any form
        with ``apply`` works; entries below 1e-14 of the largest are dropped (a sine
        basis' triple products vanish unless the wavenumbers add up).
        """
        if getattr(self, "_coo", None) is None:
            n = self.form.size
            if hasattr(self.form, "A"):
                A = self.form.A
            else:
                eye = np.eye(n)
                X = np.repeat(eye, n, axis=1)  # column j * n + k is e_j
                Y = np.tile(eye, (1, n))  # ... and e_k
                A = self.form.apply(X, Y).reshape(n, n, n)
            keep = np.abs(A) > 1e-14 * max(np.abs(A).max(), 1e-300)
            i, j, k = np.nonzero(keep)
            self._coo = (i.astype(np.int64), j.astype(np.int64), k.astype(np.int64), A[keep])
        return self._coo

    def linearization_table(self):
        """The folded tensor :math:`B_{(ij),k} = A_{ijk} + A_{ikj}` in compressed rows (cached).

        ``S(\\theta) = (B\\theta)`` reshaped to (N, N) is the form's linearization and
        :math:`q(\\theta) = \\tfrac12 S(\\theta)\\theta` its value (Euler's identity for a
        form homogeneous of degree 2). Returns ``(rows, indptr, indices, data)`` with
        ``rows`` the flat indices ``i N + j`` of the nonzero rows only.
        """
        if getattr(self, "_folded", None) is None:
            i, j, k, v = self.coordinates()
            n = self.form.size
            B = sp.coo_matrix(
                (
                    np.concatenate([v, v]),
                    (np.concatenate([i * n + j, i * n + k]), np.concatenate([k, j])),
                ),
                shape=(n * n, n),
            ).tocsr()
            B.sum_duplicates()
            counts = np.diff(B.indptr)
            rows = np.flatnonzero(counts).astype(np.int64)
            indptr = np.concatenate([[0], np.cumsum(counts[rows])]).astype(np.int64)
            self._folded = (rows, indptr, B.indices.astype(np.int64), B.data.astype(float))
        return self._folded

    def matrices(self, Theta):
        """:math:`S_k = S(\\Theta_{:,k})`, the form's linearization per chaos column, (P, N, N)."""
        return [self.form.matrix(Theta[:, k]) for k in range(Theta.shape[1])]

    def eps_jacobian(self, Theta, eps, t=None):
        return np.outer(self._raw(Theta).ravel(), self.coef.grad(eps))

    def eps_vjp(self, Theta, eps, mu, t=None):
        """:math:`(\\partial R/\\partial\\epsilon)^T\\mu` without the (NP, n_eps) matrix."""
        return self.coef.grad(eps) * float(np.vdot(self._raw(Theta), mu))


def _as_load_vector(F):
    """A load vector (N,) from an array or a sparse (N, 1) / (1, N) matrix."""
    if is_sparse(F):
        if 1 not in F.shape:
            raise ValueError(f"`F` must be a vector; got a sparse matrix of shape {F.shape}")
        F = as_operator("F", F).toarray().ravel()
    return as_finite_array("F", F, ndim=1)


class LoadTerm:
    """Load :math:`-F(\\epsilon, t)`, projected on :math:`\\mathbb E[\\Psi_\\ell]` when deterministic.

    Parameters
    ----------
    F : callable
        ``F(eps, t)`` returning ``(N,)`` (deterministic load) or ``(N, P)`` (chaos
        coefficients of a random load).
    dF : callable, optional
        ``dF(eps, t)`` returning ``(N, n_eps)`` or ``(N, P, n_eps)``; ``None`` means the
        load does not depend on :math:`\\epsilon`.

    Notes
    -----
    Use the constructors :meth:`constant`, :meth:`scaled` and :meth:`linear` for the
    common cases.
    """

    def __init__(self, F, dF=None, name="load"):
        if not callable(F):
            raise TypeError(
                f"`F` must be callable F(eps, t), got {_describe(F)}; "
                "use LoadTerm.constant(F) for a fixed array"
            )
        if dF is not None and not callable(dF):
            raise TypeError(f"`dF` must be callable dF(eps, t) or None, got {_describe(dF)}")
        self.F = F
        self.dF = dF
        self.name = name
        self.size = None  # N when known from an array (checked by the system)
        self.coef = None  # Coefficient of a scaled load (its indices are checked)
        self.n_eps = None  # columns of B for a linear load
        self._Ft = None  # F(t) of a scaled load: its values on a time grid are cached
        self._grid = (None, None)  # (time grid bytes, (n_t, N, P) table of F(t))

    @classmethod
    def constant(cls, F, name="load"):
        """Fixed load vector (a ``scipy.sparse`` column or row is accepted too)."""
        F = _as_load_vector(F)
        term = cls(lambda eps, t: F, None, name=name)
        term.size = F.shape[0]
        return term

    @classmethod
    def scaled(cls, F, coef, name="load"):
        """:math:`c(\\epsilon) F(t)`; ``F`` an ``(N,)`` array or a callable ``F(t)``."""
        coef = as_coefficient(coef)
        size = None
        if callable(F):
            Ft = F
        else:
            F = _as_load_vector(F)
            size = F.shape[0]
            Ft = lambda t: F
        term = cls(
            lambda eps, t: coef.value(eps) * Ft(t),
            lambda eps, t: np.outer(Ft(t), coef.grad(eps)),
            name=name,
        )
        term.size, term.coef, term._Ft = size, coef, Ft
        return term

    @classmethod
    def linear(cls, B, name="load"):
        """Load linear in the parameters, :math:`F = B\\,\\epsilon` (Fisher-KPP source)."""
        B = as_operator("B", B)
        dB = B.toarray() if is_sparse(B) else B  # (N, n_eps): small
        term = cls(lambda eps, t: B @ np.asarray(eps, dtype=float), lambda eps, t: dB, name=name)
        term.size, term.n_eps = B.shape
        return term

    def bind(self, E1, N=None):
        """A copy bound to a system with :math:`\\mathbb E[\\Psi]` = ``E1`` and state size ``N``
        (``self`` is unchanged)."""
        bound = copy.copy(self)
        bound._E1 = E1
        bound._N = self.size if N is None else N
        return bound

    def check_sizes(self, N, n_eps):
        """Check the sizes known from arrays against the system's ``N`` and ``n_eps``."""
        if self.size is not None and self.size != N:
            raise ValueError(
                f"load term {self.name!r}: the load has {self.size} entries but the system's "
                f"state has N={N}; pass an (N,) load matching the operators"
            )
        if self.n_eps is not None and self.n_eps != n_eps:
            raise ValueError(
                f"load term {self.name!r}: `B` has {self.n_eps} columns but the system has "
                f"n_eps={n_eps} parameters; pass B of shape (N, n_eps)"
            )

    def _chaos(self, v):
        try:
            v = np.asarray(v, dtype=float)
        except (TypeError, ValueError) as e:
            raise TypeError(
                f"load term {self.name!r}: F(eps, t) must return numbers, got {_describe(v)}"
            ) from e
        N, P = getattr(self, "_N", None), self._E1.size
        if N is not None and v.shape not in {(N,), (N, P)}:
            want = f"({N},) or ({N}, {P})" if P > 1 else f"({N},)"
            raise ValueError(
                f"load term {self.name!r}: F(eps, t) returned shape {v.shape}, expected "
                f"{want} (N={N} state size, P={P} chaos terms); fix the load's size"
            )
        if not np.isfinite(v).all():
            from ...errors import ModelEvaluationError

            raise ModelEvaluationError(f"load term {self.name!r}: F(eps, t) returned NaN or inf")
        return np.outer(v, self._E1) if v.ndim == 1 else v

    def apply(self, Theta, eps, t=None):
        return -self._chaos(call_user(self.F, f"load term {self.name!r}", "F(eps, t)", eps, t))

    def eps_jacobian(self, Theta, eps, t=None):
        N, P = Theta.shape
        if self.dF is None:
            return np.zeros((N * P, len(eps)))
        d = np.asarray(
            call_user(self.dF, f"load term {self.name!r}", "dF(eps, t)", eps, t), dtype=float
        )
        n_eps = len(eps)
        if d.shape not in {(N, n_eps), (N, P, n_eps)}:
            raise ValueError(
                f"load term {self.name!r}: dF(eps, t) returned shape {d.shape}, expected "
                f"({N}, {n_eps}) or ({N}, {P}, {n_eps}) (N, [P,] n_eps); fix the load's "
                "derivative"
            )
        if d.ndim == 2:
            d = d[:, None, :] * self._E1[None, :, None]
        return -d.reshape(N * P, len(eps))

    def on_grid(self, eps, times, derivative=False):
        """The load's chaos coefficients at every time of a grid, for a compiled march.

        Returns ``F`` of shape (n_t, N, P) and, with ``derivative``, ``dF`` of shape
        (n_t, N, P, n_eps) (else ``None``): the negated :meth:`apply` and
        :meth:`eps_jacobian` at each time. A scaled load :math:`c(\\epsilon) F(t)`
        evaluates ``F(t)`` once per time grid and keeps the table (``F(t)`` must depend
        on ``t`` only), so a march at new parameters costs no Python call per step.
        """
        N, P = self._N, self._E1.size
        n_eps = len(eps)
        zero = np.zeros((N, P))
        if self._Ft is None:
            F = np.array([-self.apply(zero, eps, t) for t in times]).reshape(-1, N, P)
            if not derivative:
                return F, None
            dF = np.array([-self.eps_jacobian(zero, eps, t) for t in times])
            return F, dF.reshape(len(times), N, P, n_eps)
        key = np.asarray(times, dtype=float).tobytes()
        if self._grid[0] != key:
            table = np.array([self._chaos(self._Ft(t)) for t in times]).reshape(-1, N, P)
            self._grid = (key, table)
        table = self._grid[1]
        F = self.coef.value(eps) * table
        if not derivative:
            return F, None
        grad = np.asarray(self.coef.grad(eps), dtype=float)
        return F, table[..., None] * grad

    def eps_vjp(self, Theta, eps, mu, t=None):
        """:math:`(\\partial R/\\partial\\epsilon)^T\\mu` without the (NP, n_eps) matrix."""
        if self.dF is None:
            return np.zeros(len(eps))
        d = np.asarray(
            call_user(self.dF, f"load term {self.name!r}", "dF(eps, t)", eps, t), dtype=float
        )
        mu = np.reshape(mu, Theta.shape)
        if d.ndim == 2:  # deterministic load: only the E[Psi] projection sees it
            return -(d.T @ (mu @ self._E1))
        return -np.einsum("ikm,ik->m", d, mu)
