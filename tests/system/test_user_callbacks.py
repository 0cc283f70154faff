"""A user's callback with the wrong signature is named in the error (issue 28)."""

import numpy as np
import pytest

from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady


def test_a_load_with_the_wrong_signature_is_named():
    system = GalerkinSystem(
        [LinearTerm(np.eye(3)), LoadTerm(lambda eps: np.ones(3), name="src")], 1
    )
    with pytest.raises(TypeError, match=r"load term 'src'.*F\(eps, t\).*eps=\[0\.5\]"):
        solve_steady(system, [0.5])


def test_a_model_reading_more_parameters_than_declared_is_named():
    system = GalerkinSystem(
        [LinearTerm(np.eye(3)), LoadTerm(lambda eps, t: eps[2] * np.ones(3), name="src")], 2
    )
    with pytest.raises(IndexError, match=r"load term 'src'.*2 parameters eps\[0\.\.1\]"):
        solve_steady(system, [0.5, 1.0])


def test_a_coefficient_with_the_wrong_signature_is_named():
    coef = Coefficient(lambda eps, t: eps[0], lambda eps: np.array([1.0]), label="k")
    system = GalerkinSystem([LinearTerm(np.eye(3), coef), LoadTerm(lambda e, t: np.ones(3))], 1)
    with pytest.raises(TypeError, match=r"coefficient k.*value\(eps\)"):
        solve_steady(system, [0.5])
