"""The map of ``ecfm_uq.inverse``'s modules in its docstring is true: every module is in
it once, and each group imports only from its own group and the groups below (the one
stated exception aside). Read from the docstring, so the doc and the check cannot drift."""

import ast
import re
from pathlib import Path

import ecfm_uq.inverse as inverse

PACKAGE = Path(inverse.__file__).parent
EXCEPTIONS = {("dynamic_fit", "dynamic")}  # stated in the docstring


def _groups():
    doc = inverse.__doc__
    lines = doc[doc.index("A map of the modules") :].splitlines()
    rules = [i for i, line in enumerate(lines) if re.fullmatch(r"=+ +=+", line)]
    groups = []
    for line in lines[rules[0] + 1 : rules[1]]:
        if not line.strip():
            continue
        if not line.startswith(" "):
            groups.append([])
        groups[-1].extend(re.findall(r":mod:`\.(\w+)`", line))
    return groups


def _imports(module):
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
            yield node.module.split(".")[0]


def test_every_module_is_on_the_map_once():
    on_map = [m for g in _groups() for m in g]
    modules = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__")
    assert sorted(on_map) == modules


def test_groups_import_only_downward():
    groups = _groups()
    level = {m: i for i, g in enumerate(groups) for m in g}
    upward = [
        (m, dep)
        for m in level
        for dep in _imports(m)
        if dep in level and level[dep] < level[m] and (m, dep) not in EXCEPTIONS
    ]
    assert upward == []
    assert [m for m in level if "fitting" in _imports(m)] == ["coverage"]
