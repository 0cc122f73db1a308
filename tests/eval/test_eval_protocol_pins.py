"""The protocol's definitions pinned in the fast tier, each against a construction whose answer is known:
the hard subset is the straight line's collisions (not the planner's), the unseen check refuses validation
scenes as well as training scenes, and a run's checkpoint is tied to the dataset it trained on (its binding)
and to its run's recorded hashes, or the results say it is not."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from samp.eval.binding import Provenance, check_binding, unverified_reason
from samp.eval.problems import Problem
from samp.scene.model import Box, Pose, Scene


# ---------------------------------------------------------------------------------------------- hard subset
class Scripted:
    """A trajectory planner that answers each problem with the path given for its name."""

    def __init__(self, robot, paths: dict):
        self.robot, self.paths, self.name = robot, paths, "scripted"

    def plan(self, problem):
        from samp.eval.planners import PlannedTrajectory

        return PlannedTrajectory(np.asarray(self.paths[problem.name]), 0.01)


def _ee(robot, q) -> np.ndarray:
    from samp.eval.checks import ee_poses

    return ee_poses(robot, np.asarray(q)[None])[0, :3, 3]


@pytest.fixture(scope="module")
def blocked(panda):
    """A scene with one box around the end effector at the middle of problem "a"'s straight joint-space line,
    and problems "a" (its line goes through the box) and "b" (turned away: its line stays clear), both
    with clear ends."""
    home = panda.home.double().numpy()
    a_start, a_goal = home + [-0.6, 0, 0, 0, 0, 0, 0], home + [0.6, 0, 0, 0, 0, 0, 0]
    mid = (a_start + a_goal) / 2
    box = Box("block", (0.08, 0.08, 0.08), Pose(tuple(float(v) for v in _ee(panda, mid))))
    scene = Scene("blocked", (box,))
    b_start, b_goal = home + [2.4, 0, 0, 0, 0, 0, 0], home + [2.8, 0, 0, 0, 0, 0, 0]
    problems = [Problem(scene, a_start, a_goal, split="val", name="a", robot="panda"),
                Problem(scene, b_start, b_goal, split="val", name="b", robot="panda")]
    return problems, mid


def test_the_hard_subset_follows_the_straight_line_not_the_planner(panda, blocked, tmp_path):
    """The planner collides on "b" only (it swings through the box) and the straight line on "a" only: the
    hard subset is {"a"}, so the planner's hard-subset collision rate is 0 and the line's 1."""
    from samp.eval.config import load_eval_config
    from samp.eval.report import Section, evaluate_sections

    problems, mid = blocked
    a, b = problems
    planner = Scripted(panda, {"a": [a.q_start], "b": [b.q_start, mid, b.q_goal]})
    cfg = load_eval_config({"record": False, "timed_problems": 0, "compare_expert": False, "problems": None})
    provenance = Provenance("data@a", "data@a", unverified="no recorded hash")  # recorded as given
    report = evaluate_sections(planner, [Section("val", problems, None, "two hand-made problems")], cfg, tmp_path,
                               provenance=provenance)
    assert (report["trained_on"], report["unverified"]) == ("data@a", "no recorded hash")
    assert "**Unverified:** no recorded hash." in (tmp_path / "metrics.md").read_text().split("\n|")[0]
    records = [json.loads(line) for line in (tmp_path / "problems.jsonl").read_text().splitlines()]
    collided = {(r["planner"], r["problem"]): r["collision"] for r in records}
    assert collided == {("scripted", "a"): False, ("scripted", "b"): True, ("straight", "a"): True,
                        ("straight", "b"): False}, f"the construction does not hold: {collided}"
    assert report["groups"]["val_hard"]["problems"] == 1
    assert report["metrics"]["val_hard"]["collision_rate"] == 0.0, "the hard subset was taken from the planner's records"
    assert report["straight"]["val_hard"]["collision_rate"] == 1.0
    assert report["metrics"]["val"]["collision_rate"] == 0.5


class GridReader(Scripted):
    """A trajectory planner that reads anchor grids (its `plan` takes `grids`, as samp+check's does)."""

    n_e = 12

    def plan(self, problem, grids=None):
        self.asked = getattr(self, "asked", []) + [None if grids is None else grids(problem, self.n_e)]
        return super().plan(problem)


def test_a_planner_that_reads_grids_gets_the_section_s_grids(panda, blocked):
    """`evaluate(..., grids=source)` hands `source` to a trajectory planner whose plan takes grids (samp+check
    with grid_source=reconstructed must not fall back to the exact grid); without a source, it gets none."""
    from samp.eval.harness import evaluate

    problems, _ = blocked
    marker = torch.full((12, 12, 12), 0.5)
    reader = GridReader(panda, {p.name: [p.q_start] for p in problems})
    evaluate(reader, problems, {"timed_problems": 0}, grids=lambda problem, n_e: marker)
    assert len(reader.asked) == 2 and all(g is marker for g in reader.asked), "the section's grids were not handed over"
    plain = GridReader(panda, {p.name: [p.q_start] for p in problems})
    evaluate(plain, problems, {"timed_problems": 0})
    assert plain.asked == [None, None]


# ---------------------------------------------------------------------------------------------- unseen check
def _dataset(splits: list[str]):
    return SimpleNamespace(scene_hashes=[f"h{i}" for i in range(len(splits))], scene_split=splits)


def _section(name: str, hashes: list[str]):
    problems = [SimpleNamespace(scene_hash=h, scene=SimpleNamespace(name=f"scene_{h}")) for h in hashes]
    return SimpleNamespace(name=name, problems=problems, benchmark="bench@0" if name == "benchmark" else None)


@pytest.mark.parametrize("split", ["train", "val"])
@pytest.mark.parametrize("section", ["test", "benchmark"])
def test_the_unseen_check_refuses_training_and_validation_scenes(split, section):
    from samp.eval.benchmark import check_unseen, trained_scene_hashes

    trained = _dataset(["train", "val", "test"])  # h0 trained on, h1 validated on, h2 never seen
    seen = trained_scene_hashes(trained)
    assert seen == {"h0", "h1"}, f"the seen scenes are the training and validation ones, got {seen}"
    clash = {"train": "h0", "val": "h1"}[split]
    with pytest.raises(ValueError, match=f"scene_{clash}.*cannot be reported as unseen"):
        check_unseen([_section(section, ["h2", clash])], seen, "ds@0")
    check_unseen([_section(section, ["h2"]), _section("val", ["h0", "h1"])], seen, "ds@0")  # the unseen one passes


# ---------------------------------------------------------------------------------------------- binding
def _ds(name: str = "data", ident: str = "aaaaaaaaaaaa"):
    return SimpleNamespace(name=name, id=ident)


def test_another_dataset_than_the_checkpoint_s_is_refused_unless_allowed(tmp_path):
    binding = SimpleNamespace(dataset_id="data@aaaaaaaaaaaa")
    assert check_binding(binding, _ds(), tmp_path, False, ["val", "train"]) == ("data@aaaaaaaaaaaa", False)
    with pytest.raises(ValueError, match=r"trained on dataset data@aaaaaaaaaaaa, not data@bbbbbbbbbbbb.*"
                                         r"allow_other_dataset=true"):
        check_binding(binding, _ds(ident="bbbbbbbbbbbb"), tmp_path, False, ["val"])
    with pytest.raises(ValueError, match="never trained on the training scenes of data@bbbbbbbbbbbb"):
        check_binding(binding, _ds(ident="bbbbbbbbbbbb"), tmp_path, True, ["val", "train"])
    assert check_binding(binding, _ds(ident="bbbbbbbbbbbb"), tmp_path, True, ["val"]) == ("data@aaaaaaaaaaaa", True)


def _run(tmp_path, record: dict | None, name: str = "last.ckpt"):
    from samp.integrity import hash_run_files

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    (run / "checkpoints" / name).write_bytes(b"weights")
    if record is not None:
        if record.pop("hashes", False):
            (run / "run.json").write_text("{}")
            record["files_sha256"] = hash_run_files(run)
        (run / "run.json").write_text(json.dumps(record))
    return run / "checkpoints" / name


def test_a_checkpoint_its_run_does_not_record_is_unverified(tmp_path):
    bound = SimpleNamespace(dataset_id="data@aaaaaaaaaaaa")
    assert unverified_reason(_run(tmp_path / "a", {"status": "completed", "hashes": True}), bound) is None
    no_hashes = _run(tmp_path / "b", {"status": "completed"})
    assert "records no files_sha256" in unverified_reason(no_hashes, bound)
    running = _run(tmp_path / "c", {"status": "running", "hashes": True})
    assert "still running" in unverified_reason(running, bound)
    ckpt = _run(tmp_path / "d", {"status": "completed", "hashes": True})
    added = ckpt.with_name("best.ckpt")
    added.write_bytes(b"another run's weights")  # copied in after the run ended: not in its record
    assert "is not among the files" in unverified_reason(added, bound)
    assert "records no dataset binding" in unverified_reason(ckpt, SimpleNamespace(dataset_id=None))
    assert "not inside a run folder" in unverified_reason(_run(tmp_path / "e", None), bound)


def test_the_report_heading_says_what_the_numbers_are_not():
    whole = Provenance("data@a", "data@a")
    assert whole.heading() == "" and whole.record()["unverified"] is None
    qualified = Provenance("data@a", "other@b", other_dataset=True, unverified="no record")
    assert "trained on data@a and is evaluated on other@b" in qualified.heading()
    assert "**Unverified:** no record." in qualified.heading()
    assert qualified.record() == {"trained_on": "data@a", "evaluated_on": "other@b", "other_dataset": True,
                                  "unverified": "no record"}


def test_policy_binding_is_read_from_the_policy_or_samp_check_s_policy():
    from samp.eval.binding import policy_binding

    binding = SimpleNamespace(dataset_id="d@1")
    system = SimpleNamespace(binding=binding)
    assert policy_binding(SimpleNamespace(system=system)) is binding
    assert policy_binding(SimpleNamespace(policy=SimpleNamespace(system=system))) is binding
    assert policy_binding(SimpleNamespace(name="straight")) is None

