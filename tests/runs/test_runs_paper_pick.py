"""Which run fills a row of the paper's tables (`samp.runs.paper`), in the fast tier, from run folders written
here: the newest completed run of the row's experiment with an evaluation, one under the current protocol
before any older one; a running run, a run without an evaluation and a run of another experiment never do;
the expert's row reads the expert block of the newest such run of any Table I experiment. A row filled by an evaluation that is not whole
(unverified, or on another dataset than the checkpoint's) says so beside its run."""

from __future__ import annotations

import json

DATASET, BENCH = "quickstart@a1b2c3d4e5f6", "bench_unseen@0f1e2d3c4b5a"


def _summary(success: int, n: int = 60) -> dict:
    return {"problems": n, "success_rate": success / n, "success_rate_ci_low": 0.0, "success_rate_ci_high": 1.0,
            "collision_rate": 0.0, "collision_rate_ci_low": 0.0, "collision_rate_ci_high": 0.1,
            "path_length_mean": 0.8, "solution_time_b1_mean": 0.01}


def _run(root, experiment: str, start: str, success: int | None, status: str = "completed", protocol: int = 2,
         **report):
    """A run folder; `success` None: no evaluation. Its expert block's success is `success` - 1, so that the
    expert row shows which run it was read from."""
    folder = root / experiment / start.replace(":", "-")
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"status": status, "experiment": experiment, "start": start,
                                                 "dataset_id": DATASET}))
    if success is not None:
        (folder / "eval").mkdir()
        body = {"planner": "samp", "dataset": DATASET, "benchmark": BENCH, "groups": {},
                "metrics": {"benchmark": _summary(success)}, "expert": {"benchmark": _summary(success - 1)},
                "straight": None, **report}
        if protocol >= 2:
            body["protocol"] = protocol
        else:  # protocol 1: train / held-out cells, no "protocol" key
            body["metrics"] = {"train": _summary(success), "heldout": _summary(success)}
        (folder / "eval" / "metrics.json").write_text(json.dumps(body))
    return folder


def _rows(root) -> dict:
    from samp.runs.paper import paper_tables
    from samp.runs.registry import find_runs

    table = paper_tables(find_runs(root), root)["table_1"]
    return {row[0]: row for row in table.rows}


def test_the_newest_completed_evaluated_run_of_the_experiment_fills_the_row(tmp_path):
    _run(tmp_path, "samp_n100", "2026-01-01T00:00:00", 40)
    picked = _run(tmp_path, "samp_n100", "2026-02-01T00:00:00", 54)
    _run(tmp_path, "samp_n100", "2026-03-01T00:00:00", 12, status="running")
    _run(tmp_path, "samp_n100", "2026-04-01T00:00:00", None)  # never evaluated
    _run(tmp_path, "samp_n100", "2026-05-01T00:00:00", 30, protocol=1)  # newer, but an older protocol
    _run(tmp_path, "samp_n160", "2026-06-01T00:00:00", 6)  # another experiment, newest of all
    rows = _rows(tmp_path)
    samp = rows["SAMP (100 anchors)"]
    assert samp[-1] == f"samp_n100/{picked.name} ({DATASET})", samp
    assert samp[3].startswith("90.0"), f"54 of 60 succeed in the picked run, got {samp[3]!r}"
    expert = rows["Expert (OMPL)"]
    newest = rows["SAMP (160 anchors)"][-1]
    assert newest.startswith("samp_n160/2026-06-01"), newest
    assert expert[3].startswith("8.3") and expert[-1] == newest, \
        f"the expert block of the newest run of any Table I experiment (5 of 60), got {expert}"



def test_a_row_from_an_evaluation_that_is_not_whole_says_so(tmp_path):
    _run(tmp_path, "samp_n100", "2026-02-01T00:00:00", 54, unverified="run.json records no files_sha256")
    _run(tmp_path, "samp_n160", "2026-02-01T00:00:00", 50, other_dataset=True, trained_on="other@0123456789ab")
    rows = _rows(tmp_path)
    assert rows["SAMP (100 anchors)"][-1].endswith("[unverified]"), rows["SAMP (100 anchors)"]
    assert rows["SAMP (160 anchors)"][-1].endswith("[trained on other@0123456789ab]"), rows["SAMP (160 anchors)"]
