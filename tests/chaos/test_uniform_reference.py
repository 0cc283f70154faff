"""Uniform inputs reproduce the results saved before the Askey-chaos change.

``tests/data/uniform_reference.npz`` was written by ``tests/data/make_uniform_reference.py``
from the code as it was before non-uniform inputs were added. Integer arrays (the selected
multi-indices) must match exactly: a different support is a different algorithm. Floating
arrays must match to a round-off tolerance relative to the array's largest entry, not bit
for bit: a reference saved on one machine is not a bit-exact contract on another BLAS,
CPU or thread count, which may sum the same products in another order.

Tolerances (relative to ``max |reference|`` of each array, so entries that are zero in
exact arithmetic are held to the array's scale instead of to themselves):

* ``1e-14`` for quadrature, Smolyak, tensors, Gram matrices and evaluations: each entry is
  a fixed sum of at most a few hundred products, whose reordering error is bounded by
  ``n * eps * max|term|`` with ``n * eps`` about 1e-14 (``eps`` = 2.2e-16).
* ``1e-12`` for the regression fits (``lstsq``, ``lars``, ``omp``, ``vector_lars``): the
  same reordering error is amplified by the condition number of the design matrices
  solved (2 to 11 for the final designs of these fits, measured once; the path's
  intermediate least-squares problems are of the same kind), with a margin of 100.

A change of algorithm moves these numbers by far more (1e-6 or more), so the test still
catches one; the one-ulp differences seen across machines (about 1e-16 relative) pass.
"""

import importlib.util
import pathlib

import numpy as np
import pytest

DATA = pathlib.Path(__file__).parents[1] / "data"
REGRESSION = ("lstsq/", "lstsq_sobol/", "lars/", "omp/", "vector_lars/")


@pytest.fixture(scope="module")
def now():
    spec = importlib.util.spec_from_file_location("make_ref", DATA / "make_uniform_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.reference()


@pytest.fixture(scope="module")
def saved():
    with np.load(DATA / "uniform_reference.npz") as f:
        return {k: f[k] for k in f.files}


def _rtol(key):
    return 1e-12 if key.startswith(REGRESSION) else 1e-14


def test_every_saved_array_is_reproduced_to_round_off(now, saved):
    assert sorted(now) == sorted(saved)
    for key, ref in saved.items():
        got = np.asarray(now[key])
        assert got.shape == ref.shape, key
        if np.issubdtype(ref.dtype, np.integer):
            np.testing.assert_array_equal(got, ref, err_msg=key)
            continue
        scale = np.max(np.abs(ref)) if ref.size else 0.0
        np.testing.assert_allclose(got, ref, rtol=0.0, atol=_rtol(key) * scale, err_msg=key)


def test_tolerance_catches_a_change_of_one_part_in_a_billion(saved):
    # The comparison is not vacuous: perturbing an entry at 1e-9 relative fails it.
    ref = saved["lars/coefficients"]
    bad = ref.copy()
    bad.flat[np.argmax(np.abs(bad))] *= 1.0 + 1e-9
    scale = np.max(np.abs(ref))
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(bad, ref, rtol=0.0, atol=_rtol("lars/") * scale)
