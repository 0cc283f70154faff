"""The layers of ``ecfm_uq.inverse`` (its docstring): ``fitting``/``coverage`` above
``formulations/`` above ``problems/`` above ``statistics/`` above ``core/``; each layer
imports only from itself and the layers below (function-level imports included), and no
module but ``coverage`` imports the entry point ``fitting``."""

import ast
from pathlib import Path

import ecfm_uq.inverse as inverse

PACKAGE = Path(inverse.__file__).parent
LAYERS = ["", "formulations", "problems", "statistics", "core"]  # top to bottom


def _layer(path):
    rel = path.relative_to(PACKAGE).parts
    return "" if len(rel) == 1 else rel[0]


def _targets(path):
    """The ``ecfm_uq.inverse`` modules (as paths relative to the package) ``path`` imports."""
    here = path.parent.relative_to(PACKAGE).parts
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level and node.module:
            base = list(here)[: len(here) - (node.level - 1)] if node.level > 1 else list(here)
            if node.level - 1 > len(here):
                continue  # outside ecfm_uq.inverse
            yield tuple(base + node.module.split("."))


def _modules():
    return [p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py"]


def test_the_docstring_names_every_layer_and_module():
    doc = inverse.__doc__
    for p in _modules():
        assert f"``{p.stem}``" in doc, p.stem
    for layer in LAYERS[1:]:
        assert f"``{layer}/``" in doc
    assert {_layer(p) for p in _modules()} == set(LAYERS)


def test_layers_import_only_downward():
    upward, entry = [], []
    for p in _modules():
        for t in _targets(p):
            layer = t[0] if t[0] in LAYERS else ""
            if LAYERS.index(layer) < LAYERS.index(_layer(p)):
                upward.append((str(p.relative_to(PACKAGE)), ".".join(t)))
            if t == ("fitting",):
                entry.append(p.stem)
    assert upward == []
    assert entry == ["coverage"]
