"""MINPACK called directly (``ecfm_uq.inverse.core.minpack``) is ``scipy.optimize.leastsq``
without its wrapper: the same point to the bit, the same return code and message, the
same Jacobian count, with and without a Jacobian; and ``leastsq`` itself when the
direct call is unavailable. The truth is scipy's public ``leastsq``."""

import numpy as np
import pytest
from scipy import optimize

from ecfm_uq.inverse.core import minpack

T = np.linspace(0.0, 4.0, 12)
Y = 3.0 * np.exp(-0.6 * T) + 0.4 + 0.01 * np.sin(7 * T)


def residual(e):
    return e[0] * np.exp(-e[1] * T) + e[2] - Y


def jacobian(e):
    g = np.exp(-e[1] * T)
    return np.column_stack([g, -e[0] * T * g, np.ones_like(T)])


CASES = [  # (jac, tolerances, maxfev): MINPACK's tests met, and its budget run out
    (None, (1e-15, 1e-15, 1e-15), 800),
    (jacobian, (1e-15, 1e-15, 1e-15), 800),
    (None, (1.49012e-8, 1.49012e-8, 0.0), 800),
    (jacobian, (1e-10, 1e-10, 0.0), 3),
]


@pytest.mark.parametrize("jac, tols, maxfev", CASES)
@pytest.mark.parametrize("route", ["direct", "leastsq"])
def test_lm_is_leastsq(jac, tols, maxfev, route, monkeypatch):
    if route == "leastsq":
        monkeypatch.setattr(minpack, "_run", [minpack._via_leastsq])
    ftol, xtol, gtol = tols
    x0 = np.array([1.0, 1.0, 0.0])
    x, info, njev = minpack.lm(residual, x0, jac, ftol=ftol, xtol=xtol, gtol=gtol, maxfev=maxfev)
    want = optimize.leastsq(residual, x0, Dfun=jac, full_output=True, ftol=ftol, xtol=xtol,
                            gtol=gtol, maxfev=maxfev)  # fmt: skip
    assert x.tobytes() == np.asarray(want[0]).tobytes()
    assert info == want[-1]
    assert minpack.minpack_message(info, ftol, xtol, gtol, maxfev) == want[-2]
    assert njev == want[2].get("njev")


def test_every_return_code_has_leastsqs_sentence():
    """Codes 6-8 (a tolerance below round-off) and 0 are hard to provoke on purpose: their
    sentences against the ones leastsq prints, read from a run that ends with each."""
    x0 = np.array([1.0, 1.0, 0.0])
    seen = {}
    for tols in [(0.0, 0.0, 0.0), (1e-300, 1.0, 0.0), (1.0, 1e-300, 0.0), (1e-300, 1e-300, 1e-300)]:
        out = optimize.leastsq(residual, x0, full_output=True, ftol=tols[0], xtol=tols[1],
                               gtol=tols[2], maxfev=800)  # fmt: skip
        seen[out[-1]] = (out[-2], tols)
    assert len(seen) >= 2
    for info, (text, (ftol, xtol, gtol)) in seen.items():
        assert minpack.minpack_message(info, ftol, xtol, gtol, 800) == text


def test_the_direct_call_checks_out_on_this_scipy():
    assert minpack._direct_works()
