"""Mistakes a user of the v0.5 pieces meets (issue 39's last item): an ODE problem, bands,
the fit as inputs, `verify`, `discover_terms`. Each is refused before any work, with a
message naming the argument and the fix; ``python tests/test_api_mistakes_v05.py`` prints
the table of docs/mistakes.md from the messages raised now."""

from __future__ import annotations

import numpy as np
import pytest

from ecfm_uq.chaos import fit_pce
from ecfm_uq.inverse import ModelProblem, OdeProblem, discover_terms, fit
from ecfm_uq.mc import verify

T = np.arange(0.0, 6.0)
DATA = np.column_stack([30 + T, 4 + T])
E = [0.5, 0.025, 0.025, 0.8]
CONC = np.array([0.02, 0.06, 0.11, 0.22, 0.56, 1.10])
RATE = np.array([76, 97, 123, 159, 191, 207.0])


def lv(t, y, e):
    return np.array([e[0] * y[0] - e[1] * y[0] * y[1], e[2] * y[0] * y[1] - e[3] * y[1]])


def mm(e):
    return e[0] * CONC / (e[1] + CONC)


def lin(x):
    return x[0] + 2 * x[1]


_CACHE = {}


def res(**kw):
    key = tuple(sorted(kw.items()))
    if key not in _CACHE:
        _CACHE[key] = fit(ModelProblem(mm, RATE), [200.0, 0.1], **kw)
    return _CACHE[key]


def pce():
    if "pce" not in _CACHE:
        _CACHE["pce"] = fit_pce(lin, [(0, 1), (0, 1)], method="quadrature", order=2)
    return _CACHE["pce"]


def _shifting(e):
    """A quantity whose shape changes away from the estimate."""
    return np.ones(3) if e[1] == res().eps[1] else np.ones(4)


#: (case, call, exception, words the message must contain)
MISTAKES_V05 = [
    ("ODE times not increasing", lambda: OdeProblem(lv, [30, 4], T[::-1], DATA, t0=0.0),
     ValueError, ["`t`", "strictly increasing", "sort"]),
    ("ODE t0 after the first datum", lambda: OdeProblem(lv, [30, 4], T, DATA, t0=1.0),
     ValueError, ["`t0`", "first datum"]),
    ("ODE observe that does not fit the data",
     lambda: OdeProblem(lv, [30, 4], T, DATA, t0=0.0, observe=[0]), ValueError,
     ["`observe`", "`data`"]),
    ("ODE rhs of the wrong shape",
     lambda: fit(OdeProblem(lambda t, y, e: np.ones(3), [30, 4], T, DATA, t0=0.0), E),
     ValueError, ["`rhs(t0, y0, eps0)`", "shape (2,)"]),
    ("ODE y0(eps) of the wrong size",
     lambda: fit(OdeProblem(lv, lambda e: e[4:], T, DATA, t0=0.0), [*E, 30.0]), ValueError,
     ["`y0(eps)`", "components"]),
    ("ODE random forces without sigma",
     lambda: fit(OdeProblem(lv, [30, 4], T, DATA, t0=0.0), E, formulation="ecfm-random"),
     ValueError, ["needs `sigma`", "formulation='ecfm'"]),
    ("predict(level=95)", lambda: res().predict(level=95), ValueError, ["`level`", "0.95"]),
    ("predict(kind='bogus')", lambda: res().predict(kind="bogus"), ValueError,
     ["`kind`", "'prediction'"]),
    ("predict with a g of changing shape", lambda: res().predict(_shifting), ValueError,
     ["`g`", "one fixed shape"]),
    ("predict with a g returning NaN", lambda: res().predict(lambda e: np.array([np.nan])),
     ValueError, ["`g`", "non-finite"]),
    ("to_inputs without a covariance",
     lambda: res(uncertainty=False).uncertainty.to_inputs(), ValueError,
     ["to_inputs", "uncertainty=True"]),
    ("to_inputs('t') with sigma given", lambda: res(sigma=5.0).uncertainty.to_inputs("t"),
     ValueError, ["kind='t'", "kind='normal'"]),
    ("verify with n = 1", lambda: verify(pce(), lin, 1), ValueError, ["`n`", ">= 2"]),
    ("verify on inputs not the surrogate's",
     lambda: verify(pce(), lin, 100, inputs=[(0, 1)] * 3), ValueError,
     ["`inputs`", "inputs=None"]),
    ("discover_terms of a fit without forces", lambda: discover_terms(res()), TypeError,
     ["`result`", "ECFM fit of an OdeProblem"]),
]  # fmt: skip


@pytest.mark.parametrize("case", MISTAKES_V05, ids=[m[0] for m in MISTAKES_V05])
def test_mistake_v05(case):
    _, call, exc, words = case
    with pytest.raises(exc) as info:
        call()
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_every_v05_mistake_is_documented():
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "mistakes.md").read_text()
    missing = [m[0] for m in MISTAKES_V05 if f"| {m[0]} |" not in doc]
    assert not missing, f"add to docs/mistakes.md: {missing}"


def _table():
    rows = ["| case | what you get now |", "|---|---|"]
    for name, call, _, _ in MISTAKES_V05:
        try:
            call()
            said = "(no error)"
        except Exception as e:  # the message is what the table shows
            said = f"`{type(e).__name__}`: {str(e).replace('|', '/')}"
        rows.append(f"| {name} | {said} |")
    return rows


if __name__ == "__main__":
    print("\n".join(_table()))
