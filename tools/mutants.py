"""Planted bugs in samp's numeric core and its evaluation protocol, and which tests catch them (a hand-made
mutation pass).

    python tools/mutants.py                 # every mutant: plant it, run its tests, restore the file
    python tools/mutants.py --only M03,M07  # some of them
    python tools/mutants.py --only protocol # the protocol pass (P*: samp/eval, samp+check, paper tables, registry)
    python tools/mutants.py --list          # what each one plants

Each mutant is one text replacement in one file (the old text must occur exactly once) and the test files
that should notice it. With the bug planted, the fast tier of the module's own test folder runs first
(`tests/<package>/ -m "not slow"`, what a developer changing that module runs); when it passes, the
mutant's listed test files run in full, slow tests included. The verdict names the tier that caught it:
"fast" (its own folder's fast tests), "slow" (only its listed files: slow tests, or tests of another folder),
"survived" when both pass, or "stale" when its text no longer occurs once in the file (the pass goes on). `--listed` runs the listed files alone (the pass as it was
before tiers). The file is always restored: in a `finally`, on Ctrl-C too, and a copy of the original is
kept in `/tmp/samp_mutants/<this tree>/` until it is restored. The tests should pass on the clean tree
first (`--baseline` checks that). Sub-processes get OMP_NUM_THREADS=1 and a per-test timeout.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BACKUP = Path("/tmp/samp_mutants") / ROOT.as_posix().strip("/").replace("/", "_")

EVAL = ("tests/eval/test_eval_metrics.py", "tests/eval/test_eval_tolerances.py")
LOSS = ("tests/policy/test_policy_losses.py",)
SDF = ("tests/scene/test_sdf.py",)
GRID = ("tests/scene/test_grid.py",)
FK = ("tests/robot/test_fk.py", "tests/robot/test_serial_fk.py")
POINTS = ("tests/robot/test_points.py",)
RSDF = ("tests/robot_sdf/test_robot_sdf_model.py", "tests/robot_sdf/test_robot_sdf_policy_inputs.py")
DATA = ("tests/data/test_data_module.py",)
STEP = ("tests/policy/test_policy_plan.py", "tests/policy/test_samp_rollout.py")
PERC = ("tests/perception/test_perception_reconstruct.py",)
SHARDS = ("tests/data/test_data_interrupt.py", "tests/data/test_data_shards.py")
PROTOCOL = ("tests/eval/test_eval_protocol_pins.py", "tests/eval/test_eval_protocol.py")
BINDING = ("tests/eval/test_eval_protocol_pins.py", "tests/eval/test_eval_binding.py")
CHECKED = ("tests/policy/test_checked_protocol.py", "tests/policy/test_policy_plan.py")
PAPER = ("tests/runs/test_runs_paper_pick.py", "tests/runs/test_runs_protocols.py")
REGISTRY = ("tests/data/test_data_registry_pins.py", "tests/data/test_data_integrity.py")
TABLES = ("tests/robot_sdf/test_robot_sdf_tables.py", "tests/robot_sdf/test_robot_points.py")


@dataclass(frozen=True)
class Mutant:
    id: str
    file: str
    old: str
    new: str
    tests: tuple[str, ...]
    what: str


MUTANTS = [
    Mutant("M01", "samp/eval/metrics.py", "ok = orientation_error < cfg.orientation_tolerance",
           "ok = orientation_error < 1.2 * cfg.orientation_tolerance", EVAL, "orientation tolerance 18 deg, not 15"),
    Mutant("M02", "samp/eval/metrics.py", "bool(ok and position_error < t)", "bool(ok and position_error < t + 0.001)",
           EVAL, "position tolerance 1 mm looser"),
    Mutant("M03", "samp/eval/checks.py", "s, seg = segment_states(traj, self.resolution)",
           "s, seg = segment_states(traj, 1e9)", EVAL, "collision sub-steps switched off"),
    Mutant("M04", "samp/eval/checks.py", "np.maximum(0.0, -world.min_distance(states[obstacle]))",
           "np.maximum(0.0, world.min_distance(states[obstacle]))", EVAL, "penetration depth sign flipped"),
    Mutant("M05", "samp/robot/goal.py", "(np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0",
           "(np.trace(relative, axis1=1, axis2=2) - 1.0) / 3.0", EVAL, "orientation error angle formula"),
    Mutant("M06", "samp/eval/rollouts.py", "(pos < self.cfg.position_tolerance) & (rot < self.cfg.orientation_tolerance)",
           "(pos < self.cfg.position_tolerance) & (rot < 2 * self.cfg.orientation_tolerance)",
           EVAL + ("tests/eval/test_eval_rollout.py",), "rollout stops at 30 deg"),
    Mutant("M07", "samp/policy/losses.py", "weights = torch.exp(-(robot_sdf.detach() - cfg.d_target) / cfg.tau)",
           "weights = torch.exp((robot_sdf.detach() - cfg.d_target) / cfg.tau)", LOSS, "collision weight sign"),
    Mutant("M08", "samp/policy/losses.py", "return diff.abs().mean() + diff.square().mean()",
           "return diff.abs().mean() + diff.square().sum()", LOSS, "match loss sums instead of averaging"),
    Mutant("M09", "samp/policy/losses.py", "return (q_pred - q_true).square().sum(dim=-1).mean()",
           "return (q_pred - q_true).square().mean()", LOSS, "config loss averages over joints"),
    Mutant("M10", "samp/scene/sdf.py", "inside = q.max(dim=-1).values.clamp(max=0)",
           "inside = q.min(dim=-1).values.clamp(max=0)", SDF, "box SDF inside uses the wrong axis"),
    Mutant("M11", "samp/scene/sdf.py", "d = torch.stack([local[..., :2].norm(dim=-1) - radius",
           "d = torch.stack([local[..., 1:].norm(dim=-1) - radius", SDF, "cylinder radius over (y, z)"),
    Mutant("M12", "samp/scene/sdf.py", 'torch.einsum("nkj,kji->nki", points[:, None, :] - t, R)',
           'torch.einsum("nkj,kij->nki", points[:, None, :] - t, R)', SDF, "obstacle frame R instead of R^T"),
    Mutant("M13", "samp/scene/grid.py", "return (2 * (points - lo) / span - 1).flip(-1)",
           "return (2 * (points - lo) / span - 1)", GRID, "grid coordinates not reordered to (z, y, x)"),
    Mutant("M14", "samp/scene/grid.py", 'mode="bilinear", padding_mode="border", align_corners=True',
           'mode="bilinear", padding_mode="border", align_corners=False', GRID, "half-voxel shift"),
    Mutant("M15", "samp/scene/grid.py", "torch.linspace(lo[i], hi[i], n_e, dtype=dtype)",
           "torch.linspace(lo[i], hi[i], n_e + 1, dtype=dtype)[:-1]", GRID, "anchors stop one spacing short"),
    Mutant("M16", "samp/robot/serial.py", "K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -z, y, z, -x, -y, x",
           "K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = z, -y, -z, x, y, -x", FK,
           "joint rotations turn the wrong way"),
    Mutant("M17", "samp/robot/serial.py", "return prefix[:, self.last + 1] @ self.D", "return prefix[:, self.last] @ self.D",
           FK, "each link takes the pose before its last joint (off by one)"),
    Mutant("M18", "samp/robot_sdf/whole_robot.py", "return torch.where(outside, f.clamp(min=0) + gap, f) * self.scales[link]",
           "return torch.where(outside, f.clamp(min=0), f) * self.scales[link]", RSDF,
           "distance outside a link's box loses the residual"),
    Mutant("M19", "samp/robot_sdf/whole_robot.py", "return torch.where(outside, f.clamp(min=0) + gap, f) * self.scales[link]",
           "return torch.where(outside, f.clamp(min=0) + gap, f)", RSDF, "link distances not scaled back to metres"),
    Mutant("M20", "samp/data/module.py", "q = q + self.noise * torch.randn(", "q = q + self.noise ** 2 * torch.randn(",
           DATA, "the noise's variance used as its std"),
    Mutant("M21", "samp/policy/step.py", "        system.fitted()\n", "", STEP, "a never-fitted system is not refused"),
    Mutant("M22", "samp/policy/step.py", "        self.system.check_env(env)\n", "", STEP,
           "grids at another n_e or bounds are not refused"),
    Mutant("M23", "samp/policy/base.py", "if not torch.allclose(env.bounds, bounds.expand_as(env.bounds), atol=1e-9):",
           "if False:", STEP, "other workspace bounds are not refused"),
    Mutant("M24", "samp/perception/reconstruct.py", "return np.where(occupied, -(inside - spacing.min()), outside)",
           "return np.where(occupied, -(inside - spacing.min()), 0.0 * outside)", PERC,
           "free space reads as distance 0"),
    Mutant("M25", "samp/perception/reconstruct.py", "        occupied[flat[inside]] = True\n", "", PERC,
           "no voxel is marked occupied"),
    Mutant("M26", "samp/expert/trajectory.py", "steps = max(1, int(np.ceil(np.linalg.norm(traj[k + 1] - traj[k]) / resolution)))",
           "steps = max(1, int(np.linalg.norm(traj[k + 1] - traj[k]) / resolution) // 2)", EVAL,
           "sub-steps twice (or more) as far apart as asked"),
    Mutant("M27", "samp/robot/model.py", "return T if self._base_is_root else self._base_inv @ T",
           "return T if self._base_is_root else T @ self._base_inv", FK + POINTS, "base frame applied on the wrong side"),
    Mutant("M28", "samp/data/generation.py", "if shard is None or j.index % num_shards == shard]",
           "if shard is None or j.index // num_shards == shard]", SHARDS, "shards take contiguous blocks of scenes"),
    Mutant("M29", "samp/eval/metrics.py", "ok = orientation_error < cfg.orientation_tolerance",
           "ok = orientation_error <= 15.0", EVAL, "the orientation tolerance ignores the config (always 15 deg)"),
    Mutant("M31", "samp/policy/losses.py", "weights = torch.exp(-(robot_sdf.detach() - cfg.d_target) / cfg.tau)",
           "weights = torch.exp(-(robot_sdf.detach() - cfg.d_target) / (2 * cfg.tau))",
           LOSS + ("tests/robot_sdf/test_robot_sdf_policy_inputs.py",), "collision weights at twice the temperature"),
    Mutant("M30", "samp/eval/callback.py", 'self.best = state_dict.get("best")', "self.best = None",
           ("tests/eval/test_eval_callback.py",), "a resumed run forgets its best evaluation score"),
]

# The protocol pass: the definitions a reported number rests on (which problems are hard, which scenes are
# unseen, what samp+check calls clear, which dataset and run a number belongs to, which run fills a table).
NEWEST = 'return max(found, key=lambda r: (r.protocol or 0, str(r.record.get("start") or ""))) if found else None'  # samp/runs/paper.py: which run fills a row
PROTOCOL_MUTANTS = [
    Mutant("P01", "samp/eval/report.py", 'straight = results.get("straight") or results[planner.name]',
           "straight = results[planner.name]", PROTOCOL, "the hard subset from the planner's records"),
    Mutant("P02", "samp/eval/report.py", "rows[section.name + HARD] = [i for i, h in enumerate(hard) if h]",
           "rows[section.name + HARD] = [i for i, h in enumerate(hard) if not h]", PROTOCOL,
           "the hard subset is where the straight line is clear"),
    Mutant("P03", "samp/eval/benchmark.py", 'if split in ("train", "val")}', 'if split == "train"}', PROTOCOL,
           "the overlap check lets validation scenes through"),
    Mutant("P04", "samp/eval/benchmark.py", "if section.name not in HELD_OUT_SECTIONS and not section.benchmark:",
           "if section.name not in HELD_OUT_SECTIONS:", PROTOCOL, "benchmark sections are never checked for seen scenes"),
    Mutant("P05", "samp/policy/checked.py", "winners = np.flatnonzero(reached & (slack > 0))",
           "winners = np.flatnonzero(reached)", CHECKED,
           "samp+check accepts a candidate whose clearance is below its margin"),
    Mutant("P06", "samp/policy/checked.py", ".view(len(q0), -1).amin(dim=1)", ".view(len(q0), -1).mean(dim=1)",
           CHECKED, "samp+check's clearance is the mean over the robot points, not the minimum"),
    Mutant("P07", "samp/policy/checked.py", "env1 = self._grid_env(problem, grids)", "env1 = self._grid_env(problem, None)",
           CHECKED, "samp+check steps and checks on the exact grid whatever the section's grid source"),
    Mutant("P08", "samp/eval/harness.py", 'extra = {"grids": grids} if grids is not None and reads_grids(planner) else {}',
           "extra = {}", CHECKED + PROTOCOL, "the evaluation does not hand samp+check the section's grids"),
    Mutant("P09", "samp/eval/report.py", "report.update(provenance.record())", "pass", BINDING,
           "metrics.json leaves out which dataset the checkpoint trained on and whether it is verified"),
    Mutant("P10", "samp/eval/binding.py", "if trained is None or given is None or trained == given:", "if True:", BINDING,
           "a checkpoint evaluated on another dataset than its own is not refused"),
    Mutant("P11", "samp/eval/binding.py", 'if "train" in splits:', "if False:", BINDING,
           "the train split of another dataset is reported as the policy's training scenes"),
    Mutant("P12", "samp/eval/binding.py", "if rel not in hashes:", "if False:", BINDING,
           "a checkpoint added after the run ended counts as verified"),
    Mutant("P13", "samp/runs/paper.py", NEWEST,
           'return max(found, key=lambda r: str(r.record.get("start") or "")) if found else None', PAPER,
           "the paper tables take the newest run whatever its evaluation protocol"),
    Mutant("P14", "samp/runs/paper.py", 'r.status == "completed" and r.evaluation]', "r.evaluation]", PAPER,
           "a running run fills a paper table's row"),
    Mutant("P15", "samp/runs/paper.py", NEWEST,
           'return min(found, key=lambda r: (r.protocol or 0, str(r.record.get("start") or ""))) if found else None',
           PAPER, "the paper tables take the oldest run"),
    Mutant("P16", "samp/data/registry.py", 'if actual != info["sha256"]:',
           'if actual != info["sha256"] and f.stat().st_size != info["size"]:', REGISTRY,
           "a changed byte that keeps the file's size passes verification"),
    Mutant("P17", "samp/data/registry.py", "body = {k: v for k, v in manifest.items() if k != MANIFEST_HASH}",
           'body = {k: v for k, v in manifest.items() if k not in (MANIFEST_HASH, "files")}', REGISTRY,
           "the manifest hash leaves out the file entries"),
    Mutant("P18", "samp/data/registry.py", 'return Path(max(candidates, key=lambda d: d["created"])["path"])',
           'return Path(min(candidates, key=lambda d: d["created"])["path"])', REGISTRY,
           "a dataset name resolves to its oldest dataset"),
    Mutant("P19", "samp/data/registry.py", r'h.update(f"{rel}\0{files[rel]}\n".encode())', r'h.update(f"{rel}\n".encode())',
           REGISTRY, "the dataset id ignores the files' contents"),
    Mutant("P20", "samp/robot_sdf/robot_points.py", "i = t.nan_to_num(0).floor().clamp(max=self.samples - 2).long()",
           "i = t.nan_to_num(0).round().clamp(max=self.samples - 2).long()", TABLES,
           "robot-SDF tables read from the nearest angle's interval, not the one below"),
    Mutant("P21", "samp/robot_sdf/robot_points.py", "v = flat[at] * (1 - f) + flat[at + 1] * f",
           "v = flat[at] * f + flat[at + 1] * (1 - f)", TABLES, "robot-SDF table interpolation weights swapped"),
]
ALL = MUTANTS + PROTOCOL_MUTANTS


def own_folder(file: str) -> str:
    """The test folder of a module: samp/eval/report.py -> tests/eval."""
    return f"tests/{Path(file).parts[1]}"


def run_tests(tests: tuple[str, ...], timeout: int, marks: str | None = None) -> tuple[bool, float, str]:
    """(passed, seconds, last output line) of pytest over the existing files (or folders) of `tests`, only
    the tests selected by `-m marks` when given."""
    paths = [t for t in tests if (ROOT / t.split("::")[0]).exists()]
    if not paths:  # pytest with no path would run the whole suite
        return True, 0.0, "no test file exists yet: nothing can catch it"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1", "RERUN_ANALYTICS": "0"}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--timeout", "240",
           *(["-m", marks] if marks else []), *paths]
    start = time.time()
    try:
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)
        tail = (proc.stdout.strip().splitlines() or [""])[-1]
        return proc.returncode == 0, time.time() - start, tail
    except subprocess.TimeoutExpired:
        return False, time.time() - start, "timed out"


class StaleMutant(ValueError):
    """A mutant whose text no longer occurs exactly once in its file (the code moved on): reported, not run."""


def plant(m: Mutant) -> tuple[Path, str]:
    path = ROOT / m.file
    text = path.read_text()
    if text.count(m.old) != 1:
        raise StaleMutant(f"the text to replace occurs {text.count(m.old)} times in {m.file}, not once: update the mutant")
    BACKUP.mkdir(parents=True, exist_ok=True)
    shutil.copy2(path, BACKUP / (m.file.replace("/", "__") + ".orig"))
    path.write_text(text.replace(m.old, m.new))
    return path, text


def verdict(m: Mutant, timeout: int, listed: bool) -> tuple[str, float, str]:
    """With `m` planted: ("fast" | "slow" | "survived" | "caught" with `listed`, seconds, last output line)."""
    if listed:
        ok, seconds, tail = run_tests(m.tests, timeout)
        return ("survived" if ok else "caught"), seconds, tail
    ok, seconds, tail = run_tests((own_folder(m.file),), timeout, marks="not slow")
    if not ok:
        return "fast", seconds, tail
    ok, more, tail = run_tests(m.tests, timeout)
    return ("survived" if ok else "slow"), seconds + more, tail


def chosen_mutants(only: str) -> list[Mutant]:
    """`--only`: ids, "protocol" (the P* pass) or "core" (the M* pass), comma-separated; empty: all."""
    if not only:
        return ALL
    wanted = set(only.split(","))
    groups = {"protocol": PROTOCOL_MUTANTS, "core": MUTANTS}
    return [m for m in ALL if m.id in wanted or any(m in groups.get(w, []) for w in wanted)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="comma-separated mutant ids, or protocol / core")
    parser.add_argument("--list", action="store_true")
    parser.add_argument("--baseline", action="store_true", help="run each mutant's tests on the clean tree only")
    parser.add_argument("--listed", action="store_true", help="run the mutant's listed test files only (no tiers)")
    parser.add_argument("--timeout", type=int, default=600, help="seconds per mutant's test run")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args()
    chosen = chosen_mutants(args.only)
    if args.list:
        for m in chosen:
            print(f"{m.id}  {m.file:34s} {m.what}  [{own_folder(m.file)} fast; {' '.join(m.tests)}]")
        return
    results = []
    for m in chosen:
        if args.baseline:
            ok, seconds, tail = run_tests(m.tests, args.timeout)
            print(f"{m.id} clean tree {'passes' if ok else 'FAILS'} ({seconds:.0f} s) {tail}", flush=True)
            continue
        try:
            path, original = plant(m)
        except StaleMutant as err:
            results.append({"id": m.id, "file": m.file, "what": m.what, "verdict": "stale", "seconds": 0})
            print(f"{m.id} stale    {err}", flush=True)
            continue
        try:
            tier, seconds, tail = verdict(m, args.timeout, args.listed)
        finally:
            path.write_text(original)
            (BACKUP / (m.file.replace("/", "__") + ".orig")).unlink(missing_ok=True)
        results.append({"id": m.id, "file": m.file, "what": m.what, "verdict": tier, "seconds": round(seconds)})
        print(f"{m.id} {tier:8s} ({seconds:4.0f} s) {m.file}: {m.what} | {tail}", flush=True)
    if results:
        caught = [r for r in results if r["verdict"] not in ("survived", "stale")]
        tiers = ", ".join(f"{sum(r['verdict'] == t for r in results)} {t}" for t in ("fast", "slow", "caught")
                          if any(r["verdict"] == t for r in results))
        print(f"caught {len(caught)} of {len(results)}" + (f" ({tiers})" if tiers else ""))
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
