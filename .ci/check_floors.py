"""Fail when .ci/min-versions.txt does not pin every core dependency at its pyproject floor."""

import re
import sys
import tomllib
from pathlib import Path

root = Path(__file__).resolve().parent.parent
deps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
floors = {}
for dep in deps:
    m = re.fullmatch(r"([A-Za-z0-9_.-]+)\s*>=\s*([0-9][0-9A-Za-z.]*)", dep.strip())
    if not m:
        sys.exit(f"pyproject.toml: dependency {dep!r} has no '>=' floor")
    floors[m.group(1).lower()] = m.group(2)
pins = {}
for line in (root / ".ci" / "min-versions.txt").read_text().splitlines():
    line = line.split("#")[0].strip()
    if line:
        name, version = line.split("==")
        pins[name.strip().lower()] = version.strip()


def release(v):
    parts = [int(x) for x in re.findall(r"\d+", v)]
    return parts + [0] * (3 - len(parts))


bad = [
    f"{name}: floor {floor}, pinned {pins.get(name)}"
    for name, floor in floors.items()
    if name not in pins or release(pins[name]) != release(floor)
]
if bad or set(pins) - set(floors):
    sys.exit(
        "min-versions.txt disagrees with pyproject.toml: "
        + "; ".join(bad or sorted(set(pins) - set(floors)))
    )
print(f"floors checked: {', '.join(f'{n} {v}' for n, v in floors.items())}")
