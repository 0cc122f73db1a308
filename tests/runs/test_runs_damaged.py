"""The run registry survives bad records (issue 21): a run.json that is not JSON, or JSON that is not a
run record, is listed as damaged with its path; every other run still lists, compares, tabulates and
fills the paper tables; opening the damaged run alone is a clear error naming the file."""

from __future__ import annotations

import json

import pytest

from samp.runs.__main__ import main
from samp.runs.registry import find_runs, load_run, scan_runs


def _load_sibling(name: str):
    """A module of this folder loaded by its path: works under every `--import-mode` (importlib puts no test
    folder on sys.path, so `from test_runs_protocols import ...` fails there)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(f"_sibling_{name}", Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


protocol_2_run = _load_sibling("test_runs_protocols").protocol_2_run

DAMAGE = {"invalid-json": '{"status": "compl', "a-list": "[1, 2]", "metrics-a-list": json.dumps({"metrics": [1, 2]})}


@pytest.fixture(params=sorted(DAMAGE))
def runs(tmp_path, request):
    good = [protocol_2_run(tmp_path, "samp_n100", "2026-03-01T00:00:00", seed=0),
            protocol_2_run(tmp_path, "samp_n100", "2026-03-02T00:00:00", seed=1)]
    bad = tmp_path / "samp_n40" / "2026-03-03T00-00-00"
    bad.mkdir(parents=True)
    (bad / "run.json").write_text(DAMAGE[request.param])
    return tmp_path, good, bad


def test_scan_names_the_damaged_record_and_keeps_the_rest(runs):
    root, good, bad = runs
    found, damaged = scan_runs(root)
    assert sorted(r.path for r in found) == sorted(good) and [r.path for r in find_runs(root)] == [r.path for r in found]
    assert [path for path, _ in damaged] == [bad / "run.json"]
    with pytest.raises(ValueError, match=rf"{bad / 'run.json'}"):
        load_run(bad)


def test_cli_lists_compares_and_tabulates_around_it(runs, capsys):
    root, good, bad = runs
    assert main(["ls", f"root={root}"]) == 0
    out = capsys.readouterr().out
    assert "2 run(s), 1 damaged:" in out and f"DAMAGED {bad / 'run.json'}" in out, out
    assert all(f"{g.parent.name}/{g.name}" in out for g in good)
    key = "eval/samp/benchmark/success_rate"
    assert main(["table", str(root), "by=experiment", f"metrics={key}"]) == 0
    captured = capsys.readouterr()
    assert "samp_n100" in captured.out and f"damaged run record, left out: {bad / 'run.json'}" in captured.err
    assert main(["compare", *map(str, good)]) == 0
    assert main(["paper-tables", f"root={root}", f"out={root / 'tables'}"]) == 0
    assert f"damaged run record, left out: {bad / 'run.json'}" in capsys.readouterr().err
    assert main(["show", str(bad)]) == 2
    assert f"{bad / 'run.json'}" in capsys.readouterr().err
