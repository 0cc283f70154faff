"""The ecfm-uq command's plumbing: help, one-line errors, atomic output, summary."""

import json
import subprocess
import sys

import numpy as np
import pytest

from ecfm_uq.cli import build_parser, main
from ecfm_uq.studies._common import to_jsonable, write_json
from ecfm_uq.summary import render_summary


def run_cli(*argv):
    return subprocess.run(
        [sys.executable, "-m", "ecfm_uq.cli", *argv], capture_output=True, text=True, timeout=300
    )


def test_help_lists_the_reproduce_command():
    r = run_cli("--help")
    assert r.returncode == 0
    assert "reproduce" in r.stdout


def test_help_of_reproduce_and_of_every_study_prints():
    from ecfm_uq.studies import available_studies

    r = run_cli("reproduce", "--help")
    assert r.returncode == 0, r.stderr
    assert "coverage" in r.stdout and "95%" in r.stdout  # a literal % in a description
    for name in available_studies():
        with pytest.raises(SystemExit) as exc:
            main(["reproduce", name, "--help"])
        assert exc.value.code == 0, name


def test_unknown_study_is_one_line_and_nonzero():
    r = run_cli("reproduce", "nosuchstudy", "--out", "x")
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "nosuchstudy" in r.stderr


def test_unknown_option_is_rejected(tmp_path):
    parser = build_parser()
    study = parser._subparsers._group_actions[0].choices["reproduce"]
    names = list(study._subparsers._group_actions[0].choices)
    r = run_cli("reproduce", names[0], "--out", str(tmp_path), "--no-such-option", "1")
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "--no-such-option" in r.stderr


def test_out_that_is_a_file_fails_cleanly(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    code = main(["reproduce", "all", "--out", str(f / "sub"), "--quiet"])
    assert code != 0
    err = capsys.readouterr().err
    assert err.startswith("ecfm-uq: error: --out") and len(err.strip().splitlines()) == 1


def test_json_refuses_non_finite_and_writes_atomically(tmp_path):
    path = tmp_path / "r.json"
    write_json(path, {"a": {"b": np.float64(1.5)}, "c": np.arange(3), "d": np.bool_(True)})
    assert json.loads(path.read_text()) == {"a": {"b": 1.5}, "c": [0, 1, 2], "d": True}
    with pytest.raises(ValueError, match="non-finite"):
        write_json(path, {"a": float("nan")})
    # the earlier file is untouched and no temporary file is left behind
    assert json.loads(path.read_text())["a"] == {"b": 1.5}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]
    with pytest.raises(ValueError):
        to_jsonable([np.inf])


def test_summary_lists_paper_and_measured_values(tmp_path):
    fig = tmp_path / "f.png"
    fig.write_bytes(b"")
    md = render_summary(
        [
            (
                "burgers",
                [{"quantity": "eps1", "paper": "1.750", "ours": "1.750", "holds": True}],
                [fig],
                None,
                1.0,
            ),
            ("kpp", [], [], "ValueError: boom", 0.1),
        ]
    )
    assert "| eps1 | 1.750 | 1.750 | yes |" in md
    assert "[f.png](burgers/f.png)" in md
    assert "**FAILED**: ValueError: boom" in md


def test_data_flows_one_way_studies_summary_cli():
    # the summary and the study registry never import the command line (no cycle)
    import ast
    from pathlib import Path

    import ecfm_uq.studies
    import ecfm_uq.summary

    for mod in (ecfm_uq.summary, ecfm_uq.studies):
        tree = ast.parse(Path(mod.__file__).read_text())
        imported = {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        assert not any(m.split(".")[-1] == "cli" for m in imported), (mod.__name__, imported)


def test_study_description_renders_as_written():
    """argparse %-formats help strings, not descriptions: '95%' stays '95%'."""
    r = run_cli("reproduce", "coverage", "--help")
    assert r.returncode == 0, r.stderr
    assert "95%" in r.stdout and "%%" not in r.stdout


def test_written_files_have_the_usual_permissions(tmp_path):
    import os
    import stat

    from ecfm_uq.plotting import pyplot, save_figure

    old = os.umask(0o022)
    try:
        write_json(tmp_path / "r.json", {"a": 1})
        fig, _ = pyplot().subplots()
        save_figure(fig, tmp_path / "f.png")
    finally:
        os.umask(old)
    for name in ("r.json", "f.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name


def test_reproduce_all_writes_a_line_per_study_to_a_log(tmp_path, monkeypatch):
    """Not a terminal (a log file under nohup or CI): one line per study with its seconds
    and folder, a skipped study says which extra installs it, the last line names
    summary.md."""
    import io

    from ecfm_uq import summary
    from ecfm_uq.studies._common import Progress

    def fake_run(name, settings, out, progress):
        (out / name).mkdir(parents=True, exist_ok=True)
        return {"name": name}

    monkeypatch.setattr(summary, "default_settings", lambda name, out, seed: {})
    monkeypatch.setattr(summary, "run_study", fake_run)
    monkeypatch.setattr(summary, "load_study", lambda name: type("M", (), {
        "summary_rows": staticmethod(lambda r: [])}))  # fmt: skip
    monkeypatch.setattr(
        summary, "missing_requirements", lambda name: [("skfem", "fem")] if name == "b" else []
    )
    log = io.StringIO()
    summary.reproduce_all(tmp_path, Progress(stream=log), names=["a", "b"])
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("a: ") and f"results in {tmp_path / 'a'}" in lines[0]
    assert lines[1] == 'b: skipped, needs skfem: pip install -e ".[fem]"'
    assert lines[-1] == f"wrote {tmp_path / 'summary.md'}"
    assert "skipped" in (tmp_path / "summary.md").read_text()


def test_a_study_without_its_extra_names_the_extra(monkeypatch):
    from ecfm_uq import studies

    monkeypatch.setattr(studies, "missing_requirements", lambda name: [("skfem", "fem")])
    with pytest.raises(RuntimeError, match=r'pip install -e "\.\[fem\]"'):
        studies.run_study("missing-physics", {}, "unused", None)


def test_reproduce_all_in_two_workers_reports_in_order_and_summarizes_the_same(tmp_path):
    """Two spawned worker processes: the per-study lines in the order of the names, and
    summary.md, as with one process (studies that fail at once: no monkeypatching
    crosses into a spawned worker, and a real study costs too much here)."""
    import io
    import re

    from ecfm_uq import summary
    from ecfm_uq.studies._common import Progress

    names = ["no-such-a", "coverage", "no-such-b"]  # "coverage" is started first
    logs, mds = [], []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        log = io.StringIO()
        with pytest.raises(RuntimeError, match="no-such-a.*coverage.*no-such-b"):
            summary.reproduce_all(out, Progress(stream=log), names=names, workers=workers,
                                  seed=-1)  # fmt: skip
        logs.append(re.sub(r"after \d+ s", "after N s", log.getvalue().replace(str(out), "OUT")))
        mds.append((out / "summary.md").read_text())
    assert logs[0] == logs[1]
    assert [line.split(":")[0] for line in logs[1].splitlines()[:3]] == names
    assert mds[0] == mds[1]
    with pytest.raises(ValueError, match="workers"):
        summary.reproduce_all(tmp_path, Progress(stream=io.StringIO()), workers=0)
