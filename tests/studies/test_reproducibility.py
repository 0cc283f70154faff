"""Hard edges of the command line: same seed gives identical JSON, user mistakes give one
line and a non-zero exit (never a traceback)."""

import json
import subprocess
import sys

import pytest

from ecfm_uq.cli import main


def _load(path):
    data = json.loads(path.read_text())
    data.pop("wall_time_s", None)
    return data


def test_same_seed_gives_identical_json(tmp_path):
    args = ["reproduce", "mc", "--samples", "400", "--workers", "1", "--seed", "7", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a = _load(tmp_path / "a" / "mc" / "result.json")
    b = _load(tmp_path / "b" / "mc" / "result.json")
    assert a == b
    assert a["settings"]["seed"] == 7


@pytest.mark.parametrize(
    "argv, word",
    [
        (["reproduce", "kpp", "--sigma", "-1"], "--sigma"),
        (["reproduce", "kpp", "--alpha", "1.5"], "--alpha"),
        (["reproduce", "beam", "--true-eps", "3.0"], "3"),
        (["reproduce", "burgers", "--epochs", "-4"], "--epochs"),
        (["reproduce", "mc", "--samples", "abc"], "--samples"),
    ],
)
def test_user_mistakes_give_one_line_and_nonzero_exit(tmp_path, argv, word):
    r = subprocess.run(
        [sys.executable, "-m", "ecfm_uq.cli", *argv, "--out", str(tmp_path), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert word in lines[0]
