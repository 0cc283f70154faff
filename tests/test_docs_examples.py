"""The tutorial in docs/getting-started.md runs and does what it says."""

import re
from pathlib import Path

import numpy as np

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_getting_started_tutorial_recovers_parameters():
    text = (DOCS / "getting-started.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    code = code.replace("    print(res)", "    results[formulation] = res")
    ns = {"results": {}}
    exec(compile(code, "getting-started.md", "exec"), ns)
    for res in ns["results"].values():
        assert res.success, res.message
        np.testing.assert_allclose(res.eps, [0.3, 2.0], rtol=1e-6)


def test_fem_tutorial_runs_and_recovers_parameters():
    import pytest

    pytest.importorskip("skfem")
    text = (DOCS / "fem.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    code = code.replace(
        "    print(formulation, res.eps, res.success)", "    results[formulation] = res"
    )
    ns = {"results": {}}
    exec(compile(code, "fem.md", "exec"), ns)
    assert ns["sol"].solver == "cg+mean"
    for res in ns["results"].values():
        assert res.success, res.message
        np.testing.assert_allclose(res.eps, [0.1, 0.5], atol=1e-6)
