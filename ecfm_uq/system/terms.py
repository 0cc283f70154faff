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

import numbers

import numpy as np

from .._validation import as_finite_array, check_int


class Coefficient:
    """Scalar coefficient :math:`c(\\epsilon)` with its gradient.

    Parameters
    ----------
    value : callable
        ``value(eps) -> float``.
    grad : callable
        ``grad(eps) -> (n_eps,)``.
    """

    def __init__(self, value, grad):
        self.value = value
        self.grad = grad

    @classmethod
    def constant(cls, c):
        """:math:`c(\\epsilon) = c`."""
        c = float(c)
        return cls(lambda eps: c, lambda eps: np.zeros(len(eps)))

    @classmethod
    def parameter(cls, index, scale=1.0):
        """:math:`c(\\epsilon) = s\\,\\epsilon_m` (e.g. the source scale :math:`\\epsilon_2`)."""
        m = check_int("index", index, minimum=0)

        def grad(eps):
            g = np.zeros(len(eps))
            g[m] = scale
            return g

        return cls(lambda eps: scale * float(eps[m]), grad)

    @classmethod
    def power10(cls, index, sign=-1.0, scale=1.0):
        """:math:`c(\\epsilon) = s\\,10^{\\pm\\epsilon_m}` (the viscosity :math:`10^{-\\epsilon_1}`)."""
        m = check_int("index", index, minimum=0)

        def value(eps):
            return scale * 10.0 ** (sign * float(eps[m]))

        def grad(eps):
            g = np.zeros(len(eps))
            g[m] = np.log(10.0) * sign * value(eps)
            return g

        return cls(value, grad)


def as_coefficient(c):
    """Accept a number or a :class:`Coefficient`."""
    if isinstance(c, Coefficient):
        return c
    if isinstance(c, numbers.Real) and not isinstance(c, bool):
        return Coefficient.constant(c)
    raise TypeError(f"`coef` must be a number or a Coefficient, got {type(c).__name__}")


class LinearTerm:
    """:math:`c(\\epsilon)\\,K\\,\\Theta\\,G` with a stochastic coupling :math:`G`.

    Parameters
    ----------
    K : (N, N) array_like
        Spatial operator.
    coef : float or Coefficient
        :math:`c(\\epsilon)`.
    G : (P, P) array_like, optional
        :math:`G_{k\\ell} = \\mathbb E[g(\\omega)\\Psi_k\\Psi_\\ell]` (symmetric). ``None``
        means :math:`g = 1`, i.e. :math:`G = \\mathbb E[\\Psi_k\\Psi_\\ell]`, supplied by the
        system.
    """

    def __init__(self, K, coef=1.0, G=None, name="linear"):
        self.K = as_finite_array("K", K, ndim=2)
        if self.K.shape[0] != self.K.shape[1]:
            raise ValueError(f"`K` must be square, got {self.K.shape}")
        self.coef = as_coefficient(coef)
        self.G = None if G is None else as_finite_array("G", G, ndim=2)
        self.name = name

    def bind(self, E2):
        """Fill the default stochastic coupling from the system's Gram matrix."""
        if self.G is None:
            self.G = E2
        self._KG = None
        if self.G.shape != E2.shape:
            raise ValueError(
                f"term {self.name!r}: `G` has shape {self.G.shape}, expected {E2.shape}"
            )

    def apply(self, Theta, eps, t=None):
        return self.coef.value(eps) * (self.K @ Theta @ self.G)

    def jacobian(self, Theta, eps, t=None):
        if getattr(self, "_KG", None) is None:
            self._KG = np.kron(self.K, self.G.T)  # fixed: only the coefficient varies
        return self.coef.value(eps) * self._KG

    def eps_jacobian(self, Theta, eps, t=None):
        base = (self.K @ Theta @ self.G).ravel()
        return np.outer(base, self.coef.grad(eps))


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
        self.form = form if hasattr(form, "matrix") else DenseQuadraticForm(form)
        self.coef = as_coefficient(coef)
        self.name = name

    def bind(self, E3):
        """Store :math:`\\mathbb E[\\Psi_a\\Psi_b\\Psi_c]` and the (b, c) pairs it couples."""
        self._E3 = np.asarray(E3, dtype=float)
        self._P = E3.shape[0]
        # q(Theta_b, Theta_c) is evaluated once per structurally nonzero pair (b, c)
        self._bs, self._cs = np.nonzero(np.any(self._E3 != 0.0, axis=0))
        self._W = self._E3[:, self._bs, self._cs].T  # (n_pairs, P)

    def _raw(self, Theta):
        if self._P == 1:
            return self.form.apply(Theta, Theta)
        return self.form.apply(Theta[:, self._bs], Theta[:, self._cs]) @ self._W

    def apply(self, Theta, eps, t=None):
        return self.coef.value(eps) * self._raw(Theta)

    def jacobian(self, Theta, eps, t=None):
        N, P = Theta.shape
        c = self.coef.value(eps)
        if P == 1:
            return c * self.form.matrix(Theta[:, 0])
        S = np.stack([self.form.matrix(Theta[:, k]) for k in range(P)])  # (P, N, N)
        # J[i, a, j, b] = sum_k E3[a, b, k] S_k[i, j], as one matrix product
        T = (self._E3.reshape(P * P, P) @ S.reshape(P, N * N)).reshape(P, P, N, N)
        return c * T.transpose(2, 0, 3, 1).reshape(N * P, N * P)

    def eps_jacobian(self, Theta, eps, t=None):
        return np.outer(self._raw(Theta).ravel(), self.coef.grad(eps))


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
            raise TypeError("`F` must be callable F(eps, t); use LoadTerm.constant for arrays")
        self.F = F
        self.dF = dF
        self.name = name

    @classmethod
    def constant(cls, F, name="load"):
        """Fixed load vector."""
        F = as_finite_array("F", F, ndim=1)
        return cls(lambda eps, t: F, None, name=name)

    @classmethod
    def scaled(cls, F, coef, name="load"):
        """:math:`c(\\epsilon) F(t)`; ``F`` an ``(N,)`` array or a callable ``F(t)``."""
        coef = as_coefficient(coef)
        if callable(F):
            Ft = F
        else:
            F = as_finite_array("F", F, ndim=1)
            Ft = lambda t: F
        return cls(
            lambda eps, t: coef.value(eps) * Ft(t),
            lambda eps, t: np.outer(Ft(t), coef.grad(eps)),
            name=name,
        )

    @classmethod
    def linear(cls, B, name="load"):
        """Load linear in the parameters, :math:`F = B\\,\\epsilon` (Fisher-KPP source)."""
        B = as_finite_array("B", B, ndim=2)
        return cls(lambda eps, t: B @ np.asarray(eps, dtype=float), lambda eps, t: B, name=name)

    def bind(self, E1):
        self._E1 = E1

    def _chaos(self, v):
        v = np.asarray(v, dtype=float)
        return np.outer(v, self._E1) if v.ndim == 1 else v

    def apply(self, Theta, eps, t=None):
        return -self._chaos(self.F(eps, t))

    def jacobian(self, Theta, eps, t=None):
        return None  # no dependence on Theta

    def eps_jacobian(self, Theta, eps, t=None):
        N, P = Theta.shape
        if self.dF is None:
            return np.zeros((N * P, len(eps)))
        d = np.asarray(self.dF(eps, t), dtype=float)
        if d.ndim == 2:
            d = d[:, None, :] * self._E1[None, :, None]
        return -d.reshape(N * P, len(eps))
