"""The decay tutorial of docs/time.md runs, fits in 20 lines and meets the closed form."""

import re
from pathlib import Path

import numpy as np

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_decay_tutorial_in_docs_meets_the_closed_form_to_1e_8():
    code = re.findall(r"```python\n(.*?)```", (DOCS / "time.md").read_text(), re.S)[0]
    assert len([line for line in code.splitlines() if line.strip()]) <= 20
    ns = {}
    exec(compile(code, "time.md", "exec"), ns)
    t = ns["t"]
    safe = np.where(t > 0, t, 1.0)

    def mgf(k):  # E[exp(-k beta t)], beta ~ U(0.1, 0.2)
        e = (np.exp(-0.1 * k * safe) - np.exp(-0.2 * k * safe)) / (0.1 * k * safe)
        return np.where(t > 0, e, 1.0)

    mean = 1.5 * mgf(1)
    assert np.abs(ns["mean"] - mean).max() < 1e-8
    assert np.abs(ns["variance"] - ((1.5**2 + 0.2**2) * mgf(2) - mean**2)).max() < 1e-8
