"""A user's own continuous law, shared by the tests and ``benchmarks/pce_peers.py``.

Imported through conftest's path entry by the tests, and by the benchmark through its own
(``--part mixed`` uses the law the tests check). Not part of the library: a user writes
such a law; ``ecfm_uq`` only has to accept it.
"""

import numpy as np
from scipy import stats


class TruncGumbel(stats.rv_continuous):
    """Gumbel (max) law, location 10, scale 2, truncated to [5, 25]: a user's own law."""

    def _g(self, x):
        return np.exp(-np.exp(-(x - 10.0) / 2.0))

    def _pdf(self, x):
        z = (x - 10.0) / 2.0
        return np.exp(-z - np.exp(-z)) / 2.0 / (self._g(25.0) - self._g(5.0))

    def _cdf(self, x):
        return (self._g(x) - self._g(5.0)) / (self._g(25.0) - self._g(5.0))

    def _ppf(self, u):
        return 10.0 - 2.0 * np.log(-np.log(self._g(5.0) + u * (self._g(25.0) - self._g(5.0))))


#: the law itself (a frozen instance is ``TRUNC_GUMBEL()``)
TRUNC_GUMBEL = TruncGumbel(a=5.0, b=25.0, name="truncgumbel")
