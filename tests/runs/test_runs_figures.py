"""A run's pictures from its files (samp.runs.figures): learning curves per loss term with the learning
rate, outcomes with Wilson intervals, success against difficulty. Real files in a run folder; the SDF
slice (which needs a dataset) is drawn by the end-to-end demo test."""

from __future__ import annotations

import json

import pytest

from samp.runs.figures import plot_learning, plot_outcomes, plot_run
from samp.runs.registry import Run

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

PNG = b"\x89PNG"


def _run(tmp_path, csv: str, records: list[dict] | None = None) -> Run:
    (tmp_path / "metrics.csv").write_text(csv)
    if records is not None:
        (tmp_path / "eval").mkdir()
        (tmp_path / "eval" / "problems.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return Run(tmp_path, {"experiment": "figures"})


CSV = ("epoch,step,train/loss,train/match,train/coll,val/loss,val/match,val/coll,lr-AdamW\n"
       "0,0,,,,,,,0.001\n0,9,1.0,0.5,0.01,,,,0.0009\n0,9,,,,0.8,0.4,0.02,\n1,19,0.5,0.2,0.0,,,,0.0005\n")


def _record(planner: str, problem: int, success: bool, collision: bool, error: float) -> dict:
    return {"planner": planner, "problem": f"p{problem}", "group": "val", "success": {"2cm": success},
            "collision": collision, "position_error": error}


def test_learning_curves_and_outcomes_are_drawn_from_the_run_files(tmp_path):
    records = [_record(p, i, s, c, e) for i in range(4)
               for p, s, c, e in (("samp", i % 2 == 0, False, 0.01 * (i + 1)), ("expert", True, False, 0.0),
                                  ("straight", i < 2, i >= 2, 0.015))]
    run = _run(tmp_path, CSV, records)
    written = plot_run(run)
    assert [p.name for p in written] != [] and {p.name for p in written} == {"learning.png", "outcomes.png"}
    for path in written:
        assert path.parent == tmp_path / "plots" and path.read_bytes()[:4] == PNG


def test_a_run_without_losses_is_a_clear_error(tmp_path):
    run = _run(tmp_path, "epoch,step,eval/success_rate\n0,9,0.5\n")
    with pytest.raises(ValueError, match="no train/ or val/ losses in its metrics.csv"):
        plot_learning(run, tmp_path / "learning.png")
    assert plot_run(run) == []  # nothing to draw, nothing written


def test_outcomes_need_an_evaluation(tmp_path):
    run = _run(tmp_path, CSV)
    with pytest.raises(ValueError, match="was not evaluated"):
        plot_outcomes(run, tmp_path / "outcomes.png")
