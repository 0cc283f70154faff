"""The layers of ``ecfm_uq.system``: ``model/`` (terms, the system, its operators,
trajectories, status codes) below ``solve/`` (plan, linear and Newton solvers, compiled
marches) below ``time/`` (the time family) below the package itself (steady solves, the
public names, the former module paths); each layer imports only from itself and the
layers below, function-level imports included."""

import ast
import importlib
from pathlib import Path

import ecfm_uq.system as system

PACKAGE = Path(system.__file__).parent
LAYERS = ["", "time", "solve", "model"]  # top to bottom


def _layer(path):
    rel = path.relative_to(PACKAGE).parts
    return "" if len(rel) == 1 else rel[0]


def _targets(path, source=None):
    """The ``ecfm_uq.system`` modules (as tuples of parts) that ``path`` (or ``source``
    read as the text of ``path``) imports."""
    here = list(path.parent.relative_to(PACKAGE).parts)
    for node in ast.walk(ast.parse(path.read_text() if source is None else source)):
        if not (isinstance(node, ast.ImportFrom) and node.level):
            continue
        if node.level - 1 > len(here):
            continue  # outside ecfm_uq.system
        base = here[: len(here) - (node.level - 1)]
        if node.module:
            yield tuple(base + node.module.split("."))
        else:
            for alias in node.names:
                yield tuple([*base, alias.name])


def test_every_module_sits_on_a_layer():
    layers = {_layer(p) for p in PACKAGE.rglob("*.py")}
    assert layers == set(LAYERS)


def _upward(path, source=None):
    """The imports of ``path`` that reach a higher layer."""
    found = []
    for t in _targets(path, source):
        layer = t[0] if t and t[0] in LAYERS else ""
        if LAYERS.index(layer) < LAYERS.index(_layer(path)):
            found.append((str(path.relative_to(PACKAGE)), ".".join(t)))
    return found


def test_layers_import_only_downward():
    assert [u for p in PACKAGE.rglob("*.py") for u in _upward(p)] == []


def test_the_layout_check_sees_an_upward_import():
    """The check above can fail: imports of a higher layer (module- or function-level,
    ``from . import`` form too) are caught, same-layer and lower ones are not."""
    terms = PACKAGE / "model" / "terms.py"
    source = (
        "from . import operator\n"
        "from ...errors import ModelEvaluationError\n"
        "def f():\n"
        "    from ..solve.plan import plan_solve\n"
        "    from .. import steady\n"
    )
    assert _upward(terms, source) == [
        ("model/terms.py", "solve.plan"),
        ("model/terms.py", "steady"),
    ]
    assert _upward(PACKAGE / "time" / "bdf.py", "from ..solve.plan import NEWTON_ETA_MAX\n") == []


def test_former_module_paths_name_the_same_objects():
    """``system.plan``, ``linear``, ``trajectory``, ``galerkin`` stay importable (callers
    outside ``ecfm_uq.system`` use them) and hand out the moved objects themselves."""
    for old, new in [
        ("plan", "solve.plan"),
        ("linear", "solve.linear"),
        ("trajectory", "model.trajectory"),
        ("galerkin", "model.galerkin"),
    ]:
        before = importlib.import_module(f"ecfm_uq.system.{old}")
        after = importlib.import_module(f"ecfm_uq.system.{new}")
        assert before.__all__, old
        for name in before.__all__:
            assert getattr(before, name) is getattr(after, name), (old, name)
