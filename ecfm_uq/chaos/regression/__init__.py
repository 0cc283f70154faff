"""Sparse polynomial chaos regression: LAR/OMP paths, leave-one-out errors, adaptivity.

The regression behind ``fit_pce(method="lars" | "omp")`` (Blatman & Sudret 2011), one
concept in five modules, each importing only the ones below it:

* :mod:`.fit` -- the sparse fit itself (:func:`fit_sparse`): candidate sets of a fixed
  q-norm up to the candidate degree (:func:`candidate_degree`), in design or Gram form,
  and the compression of field outputs;
* :mod:`.adaptive` -- the default, degree- and q-norm-adaptive candidate sets
  (:func:`hyperbolic_indices`), grown while affordable and improving;
* :mod:`.paths` -- the order in which the candidate columns enter a least-angle
  regression or orthogonal matching pursuit path (design or Gram form), and the hybrid
  selection that refits every nested active set by OLS;
* :mod:`.loo` -- the corrected leave-one-out errors of all nested refits at once
  (:func:`loo_nested`);
* :mod:`.compression` -- the principal components of a field output (PCA-PCE), on which
  the selection runs (``compress_outputs``, a streaming sketch).

Public API
----------
fit_sparse          the sparse fit of :func:`~ecfm_uq.chaos.fit_pce` (LARS / OMP)
candidate_degree    the default largest candidate degree and the rule that set it
hyperbolic_indices  the multi-indices of a hyperbolic (q-norm) candidate set
loo_nested          corrected leave-one-out errors of nested OLS fits from one QR
path_order          the order in which columns enter a LARS or OMP path
"""

from .adaptive import hyperbolic_indices
from .fit import candidate_degree, fit_sparse
from .loo import loo_nested
from .paths import path_order

__all__ = ["candidate_degree", "fit_sparse", "hyperbolic_indices", "loo_nested", "path_order"]
