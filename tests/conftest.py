"""Test configuration: make the shared test models (``tests/_models.py``) importable; under
pytest-xdist, one BLAS thread per worker."""

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

if os.environ.get("PYTEST_XDIST_WORKER"):
    # The workers share the cores (`pytest -n auto`: one per core), so each runs its BLAS
    # on one thread. The library still decides per call (ecfm_uq.threads: one thread for
    # small work, the process's threads for large), and the process's threads are now
    # one: a large dense solve no longer oversubscribes the cores with the other worker.
    # numpy and scipy each load their own OpenBLAS: both are loaded before the limit.
    # tests/test_threads.py raises the limit inside its own tests, so it still tests the
    # library's decision.
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
