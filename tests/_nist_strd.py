"""The NIST StRD nonlinear regression problems, read from their certified files and
written as a user of ``ecfm_uq`` would write them.

Each problem becomes a model with one state per observation, :math:`\\theta_i =
f(x_i; \\epsilon)`: a unit ``LinearTerm`` and a ``LoadTerm(F, dF)`` whose ``dF`` is
:math:`\\partial f/\\partial\\epsilon` to round-off (complex-step differentiation of the
model formula, :math:`\\operatorname{Im} f(\\epsilon + ih e_k)/h` with :math:`h =
10^{-30}`: no truncation and no cancellation), every state observed.

The model formulas are typed from the ``Model:`` block of each file (checked against
it by :func:`test_model_formula_is_the_files`); data, starts, certified values and
standard deviations are parsed from the files (``tests/data/nist_strd``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent / "data" / "nist_strd"


#: f(b, x) for each problem (numpy, complex-safe); x is (n,) or, for Nelson, (n, 2)
MODELS = {
    "Misra1a": lambda b, x: b[0] * (1 - np.exp(-b[1] * x)),
    "Chwirut1": lambda b, x: np.exp(-b[0] * x) / (b[1] + b[2] * x),
    "Chwirut2": lambda b, x: np.exp(-b[0] * x) / (b[1] + b[2] * x),
    "Lanczos1": lambda b, x: (
        b[0] * np.exp(-b[1] * x) + b[2] * np.exp(-b[3] * x) + b[4] * np.exp(-b[5] * x)
    ),
    "Gauss1": lambda b, x: (
        b[0] * np.exp(-b[1] * x)
        + b[2] * np.exp(-((x - b[3]) ** 2) / b[4] ** 2)
        + b[5] * np.exp(-((x - b[6]) ** 2) / b[7] ** 2)
    ),
    "DanWood": lambda b, x: b[0] * x ** b[1],
    "Misra1b": lambda b, x: b[0] * (1 - (1 + b[1] * x / 2) ** (-2)),
    "Kirby2": lambda b, x: (b[0] + b[1] * x + b[2] * x**2) / (1 + b[3] * x + b[4] * x**2),
    "Hahn1": lambda b, x: (
        (b[0] + b[1] * x + b[2] * x**2 + b[3] * x**3) / (1 + b[4] * x + b[5] * x**2 + b[6] * x**3)
    ),
    "Nelson": lambda b, x: b[0] - b[1] * x[:, 0] * np.exp(-b[2] * x[:, 1]),
    "MGH17": lambda b, x: b[0] + b[1] * np.exp(-x * b[3]) + b[2] * np.exp(-x * b[4]),
    "Misra1c": lambda b, x: b[0] * (1 - (1 + 2 * b[1] * x) ** (-0.5)),
    "Misra1d": lambda b, x: b[0] * b[1] * x * ((1 + b[1] * x) ** (-1)),
    "Roszman1": lambda b, x: b[0] - b[1] * x - np.arctan(b[2] / (x - b[3])) / np.pi,
    "ENSO": lambda b, x: (
        b[0]
        + b[1] * np.cos(2 * np.pi * x / 12)
        + b[2] * np.sin(2 * np.pi * x / 12)
        + b[4] * np.cos(2 * np.pi * x / b[3])
        + b[5] * np.sin(2 * np.pi * x / b[3])
        + b[7] * np.cos(2 * np.pi * x / b[6])
        + b[8] * np.sin(2 * np.pi * x / b[6])
    ),
    "MGH09": lambda b, x: b[0] * (x**2 + x * b[1]) / (x**2 + x * b[2] + b[3]),
    "BoxBOD": lambda b, x: b[0] * (1 - np.exp(-b[1] * x)),
    "Rat42": lambda b, x: b[0] / (1 + np.exp(b[1] - b[2] * x)),
    "MGH10": lambda b, x: b[0] * np.exp(b[1] / (x + b[2])),
    "Eckerle4": lambda b, x: (b[0] / b[1]) * np.exp(-0.5 * ((x - b[2]) / b[1]) ** 2),
    "Rat43": lambda b, x: b[0] / ((1 + np.exp(b[1] - b[2] * x)) ** (1 / b[3])),
    "Bennett5": lambda b, x: b[0] * (b[1] + x) ** (-1 / b[2]),
}
MODELS["Lanczos2"] = MODELS["Lanczos3"] = MODELS["Lanczos1"]
MODELS["Gauss2"] = MODELS["Gauss3"] = MODELS["Gauss1"]
MODELS["Thurber"] = MODELS["Hahn1"]

#: every problem of the suite
NAMES = sorted(MODELS)


@dataclass(frozen=True)
class StRD:
    """One certified problem."""

    name: str
    y: np.ndarray  # (n,) response (log y for Nelson)
    x: np.ndarray  # (n,) or (n, 2)
    starts: tuple  # (start1, start2), each (p,)
    certified: np.ndarray  # (p,)
    certified_sd: np.ndarray  # (p,)
    rss: float
    difficulty: str
    formula: str

    def f(self, b):
        return MODELS[self.name](b, self.x)

    def df(self, b):
        """(n, p) derivative of the model in the parameters, by complex step."""
        b = np.asarray(b, dtype=float)
        h = 1e-30
        cols = []
        for k in range(b.size):
            bc = b.astype(complex)
            bc[k] += 1j * h
            cols.append(np.imag(MODELS[self.name](bc, self.x)) / h)
        return np.column_stack(cols)


_NUM = r"[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?"


def load(name):
    """Parse ``tests/data/nist_strd/<name>.dat``."""
    lines = (DATA / f"{name}.dat").read_text().splitlines()
    rows = [ln for ln in lines if re.match(r"\s*b\d+\s*=", ln)]
    table = np.array([[float(t) for t in re.findall(_NUM, ln.split("=", 1)[1])] for ln in rows])
    rss = next(float(re.findall(_NUM, ln)[0]) for ln in lines if "Residual Sum of Squares" in ln)
    difficulty = next(ln.split()[0] for ln in lines if "Level of Difficulty" in ln)
    start = next(i for i, ln in enumerate(lines) if ln.startswith("Model:"))
    stop = next(i for i, ln in enumerate(lines) if i > start and "starting values" in ln.lower())
    formula = " ".join(ln.strip() for ln in lines[start + 3 : stop] if ln.strip())
    first = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["Data:", "y"])
    data = np.array(
        [[float(t) for t in ln.split()] for ln in lines[first + 1 :] if ln.strip()], dtype=float
    )
    y, x = data[:, 0], data[:, 1] if data.shape[1] == 2 else data[:, 1:]
    if name == "Nelson":  # the response is log[y]
        y = np.log(y)
    return StRD(
        name, y, x, (table[:, 0], table[:, 1]), table[:, 2], table[:, 3], rss, difficulty, formula
    )
