"""A multivariate Student t as model inputs, on independent germs.

:math:`x \\sim t_\\nu(\\mu, S)` (location :math:`\\mu`, scale matrix :math:`S`, :math:`\\nu`
degrees of freedom) is a normal scale mixture,

.. math::

    x = \\mu + L\\xi\\,\\sqrt{\\nu / W}, \\qquad LL^T = S,\\quad
    \\xi \\sim N(0, I_p),\\quad W = 2g \\sim \\chi^2_\\nu,\\quad g \\sim \\Gamma(\\nu/2),

so it is reached from :math:`p + 1` independent germs: :math:`p` standard normals
(Hermite) and one gamma variable of shape :math:`\\nu/2` (Laguerre), the scale shared by
all inputs. This is the marginal posterior of a linear model's parameters when the noise
level is estimated (Jeffreys prior, :math:`\\nu = n - p`), what
:meth:`~ecfm_uq.inverse.Uncertainty.to_inputs` returns for ``kind="t"``.

The chaos basis therefore has ``dim = p + 1`` variables while the model takes ``p``
inputs (``n_inputs``). The map is not one-to-one (``to_germ`` is refused): a PCE of these
inputs is evaluated on germ points (``pce.evaluate``, ``pce.sample``), not at given
inputs. ``x`` is not polynomial in :math:`g` (:math:`g^{-1/2}`): for few degrees of
freedom the expansion converges slowly and the variance exists only for :math:`\\nu > 2`.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from .._validation import as_finite_array
from .germs import Germ
from .inputs import Inputs, draw_germs
from .marginals import as_marginal

__all__ = ["StudentInputs"]


class StudentInputs(Inputs):
    """Inputs :math:`x \\sim t_\\nu(\\mu, S)`, multivariate Student t.

    Parameters
    ----------
    loc : (p,) array_like
        Location :math:`\\mu` (the mean for :math:`\\nu > 1`).
    scale : (p, p) array_like
        Scale matrix :math:`S`, symmetric positive definite (the covariance is
        :math:`S\\nu/(\\nu - 2)`).
    dof : float
        Degrees of freedom :math:`\\nu > 0`.
    names : sequence of str, optional
        Names of the ``p`` inputs (default ``x0, x1, ...``).

    Attributes
    ----------
    dim : int
        Number of chaos (germ) variables, ``p + 1``: ``p`` standard normals and the
        shared gamma scale variable (named ``"chi2_scale"`` in :attr:`germ_names`).
    n_inputs : int
        ``p``, the number of model inputs (columns of :meth:`from_germ`).
    germs : tuple of Germ
    names : tuple of str
        The ``p`` input names.
    dependent : bool
        ``True`` (the inputs share the scale variable, and :math:`S` may correlate them).

    Raises
    ------
    ValueError
        Misshaped, non-symmetric or not positive definite ``scale``, ``dof <= 0``.
    """

    def __init__(self, loc, scale, dof, names=None):
        mu = as_finite_array("loc", loc, ndim=1)
        p = mu.size
        S = as_finite_array("scale", scale, shape=(p, p))
        if not np.allclose(S, S.T, rtol=1e-10, atol=0):
            raise ValueError("`scale` must be a symmetric matrix")
        try:
            self._L = np.linalg.cholesky(0.5 * (S + S.T))
        except np.linalg.LinAlgError:
            raise ValueError("`scale` must be positive definite") from None
        dof = float(dof)
        if not (np.isfinite(dof) and dof > 0):
            raise ValueError(f"`dof` must be a positive number, got {dof!r}")
        if names is None:
            names = [f"x{k}" for k in range(p)]
        names = tuple(str(n) for n in names)
        if len(names) != p:
            raise ValueError(f"`names` must hold {p} names, got {len(names)}")
        self.loc, self.scale, self.dof, self.names = mu, 0.5 * (S + S.T), dof, names
        self.germs = (Germ("hermite"),) * p + (Germ("laguerre", shape=dof / 2),)
        self.germ_names = (*names, "chi2_scale")
        sd = np.sqrt(np.diag(self.scale))
        self.correlation = self.scale / np.outer(sd, sd)
        self.dependent = True
        self.affine = False

    @property
    def dim(self):
        """Number of chaos variables, ``n_inputs + 1``."""
        return self.n_inputs + 1

    @property
    def n_inputs(self):
        """Number of model inputs."""
        return self.loc.size

    @property
    def marginals(self):
        """Each input's law, :math:`t_\\nu(\\mu_k, \\sqrt{S_{kk}})`, as a
        :class:`~ecfm_uq.chaos.marginals.Marginal`."""
        sd = np.sqrt(np.diag(self.scale))
        return tuple(
            as_marginal(stats.t(self.dof, m, s), n)
            for m, s, n in zip(self.loc, sd, self.names, strict=True)
        )

    def __repr__(self):
        return f"StudentInputs({', '.join(self.names)}; dof={self.dof:g})"

    def __eq__(self, other):
        if not isinstance(other, StudentInputs):
            return NotImplemented
        return (
            np.array_equal(self.loc, other.loc)
            and np.array_equal(self.scale, other.scale)
            and self.dof == other.dof
        )

    __hash__ = None

    def from_germ(self, omega):
        """Input points ``(n, p)`` of germ points ``(n, p + 1)`` (normals, then the gamma
        variable): :math:`\\mu + L\\xi\\sqrt{\\nu/(2g)}`."""
        g = as_finite_array("omega", omega)
        if g.ndim == 1 and g.size == self.dim:
            g = g[None, :]
        if g.ndim != 2 or g.shape[1] != self.dim:
            raise ValueError(
                f"`omega` must have shape (n, {self.dim}): {self.n_inputs} normals and the "
                f"gamma scale variable, got {g.shape}"
            )
        if np.any(g[:, -1] <= 0):
            raise ValueError("`omega`'s last column (the gamma scale variable) must be > 0")
        return self.loc + (g[:, :-1] @ self._L.T) * np.sqrt(self.dof / (2.0 * g[:, -1:]))

    def to_germ(self, x):
        """Refused: ``p`` inputs do not determine the ``p + 1`` germ variables."""
        raise ValueError(
            "StudentInputs.to_germ: the multivariate t is a scale mixture of p + 1 germ "
            "variables, so input points do not determine germ points; evaluate a PCE of "
            "these inputs on germ points (pce.evaluate, pce.sample) or use "
            "Inputs.from_samples(inputs.sample(n)) for an invertible approximation"
        )

    def sample(self, n, seed=None):
        """``n`` random input points, ``(n, p)``."""
        return self.from_germ(draw_germs(self.germs, n, seed))

    def to_chaospy(self):
        """Refused: chaospy has no multivariate t here."""
        raise ValueError("StudentInputs has no chaospy equivalent; sample it with .sample(n)")
