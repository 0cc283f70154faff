"""Uniform inputs stay bit-identical to the results saved before the Askey-chaos change.

``tests/data/uniform_reference.npz`` was written by ``tests/data/make_uniform_reference.py``
from the code as it was before non-uniform inputs were added; every array must be
reproduced exactly (``assert_array_equal``, not a tolerance).
"""

import importlib.util
import pathlib

import numpy as np
import pytest

DATA = pathlib.Path(__file__).parents[1] / "data"


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


def test_every_saved_array_is_reproduced_bit_for_bit(now, saved):
    assert sorted(now) == sorted(saved)
    for key, ref in saved.items():
        np.testing.assert_array_equal(now[key], ref, err_msg=key)
