"""The paper's metrics (DESIGN section 4) from per-problem records, and their markdown table.

A record is one problem's outcome (JSON-ready): `reached` per position tolerance (final end-effector
position error below it and orientation error below the orientation tolerance), the violations found by
`samp.eval.checks`, the end-effector path length, the solution time and the per-step inference times.

  success rate   reached and no violation (collision, self-collision, joint limits), per tolerance
  reach rate     reached, whatever happened on the way
  collision rate penetration of an obstacle at a step or sub-step; self-collision and joint-limit rates
                 apart, and `violation_rate` for any of the three
  path length    sum of ||dp_ee|| over the executed waypoints, metres: mean and std over the successful
                 problems (a failed path's length says little), and over all problems as `path_length_all`
  solution time  wall time spent producing each trajectory (seconds), over all problems
  inference time wall time per policy step call (seconds), over every step of every problem
"""

from __future__ import annotations

import numpy as np

from samp.eval.config import RolloutConfig, tolerance_label

__all__ = ["TABLE_COLUMNS", "markdown_table", "reached_within", "summarize"]


def reached_within(position_error: float | None, orientation_error: float | None, cfg: RolloutConfig) -> dict[str, bool]:
    """{"2cm": bool, "1cm": bool, ...}: the final pose within each position tolerance and the orientation one."""
    if position_error is None or orientation_error is None:
        return {tolerance_label(t): False for t in cfg.tolerances()}
    ok = orientation_error < cfg.orientation_tolerance
    return {tolerance_label(t): bool(ok and position_error < t) for t in cfg.tolerances()}


def _stats(values: list[float]) -> tuple[float | None, float | None]:
    """(mean, std) with numpy's population std; (None, None) for no values."""
    if not values:
        return None, None
    arr = np.asarray(values, dtype=np.float64)
    return float(arr.mean()), float(arr.std())


def summarize(records: list[dict], cfg: RolloutConfig) -> dict:
    """The metrics of `records` (one problem each); rates are fractions in [0, 1]."""
    n = len(records)
    if n == 0:
        return {"problems": 0}
    rate = lambda flags: float(np.mean([bool(f) for f in flags]))  # noqa: E731
    violation = [r["collision"] or r["self_collision"] or r["joint_limit_violation"] for r in records]
    primary = tolerance_label(cfg.position_tolerance)
    out: dict = {"problems": n}
    for label in (tolerance_label(t) for t in cfg.tolerances()):
        reached = [r["reached"][label] for r in records]
        out[f"success_rate@{label}"] = rate([a and not v for a, v in zip(reached, violation)])
        out[f"reach_rate@{label}"] = rate(reached)
    out["success_rate"], out["reach_rate"] = out[f"success_rate@{primary}"], out[f"reach_rate@{primary}"]
    out["collision_rate"] = rate(r["collision"] for r in records)
    out["self_collision_rate"] = rate(r["self_collision"] for r in records)
    out["joint_limit_rate"] = rate(r["joint_limit_violation"] for r in records)
    out["violation_rate"] = rate(violation)
    success = [r["reached"][primary] and not v for r, v in zip(records, violation)]
    lengths = [r["path_length"] for r, s in zip(records, success) if s and r["path_length"] is not None]
    out["path_length_mean"], out["path_length_std"] = _stats(lengths)
    out["path_length_all_mean"], out["path_length_all_std"] = _stats(
        [r["path_length"] for r in records if r["path_length"] is not None])
    out["solution_time_mean"], out["solution_time_std"] = _stats(
        [r["solution_time"] for r in records if r["solution_time"] is not None])
    out["inference_time_mean"], out["inference_time_std"] = _stats([t for r in records for t in r["step_times"]])
    out["steps_mean"], _ = _stats([r["steps"] for r in records])
    depths = [r["collision_depth"] for r in records if r["collision"]]
    out["collision_depth_mean"], out["collision_depth_max"] = _stats(depths)[0], max(depths) if depths else None
    terminations: dict[str, int] = {}
    for r in records:
        terminations[r["termination"]] = terminations.get(r["termination"], 0) + 1
    out["terminations"] = terminations
    return out


TABLE_COLUMNS = ["planner", "split", "problems", "soln. time [s]", "path length [m]", "success [%]", "reach [%]",
                 "collision [%]", "self-coll. [%]", "joint limits [%]", "step [ms]"]


def _pm(mean, std, scale: float = 1.0, digits: int = 3) -> str:
    return "-" if mean is None else f"{mean * scale:.{digits}f} ± {std * scale:.{digits}f}"


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


def markdown_table(rows: list[tuple[str, str, dict]], cfg: RolloutConfig) -> str:
    """(planner, split, metrics) rows -> a markdown table in the paper's Table I/II style; success and
    reach are given at every tolerance (the stopping tolerance first)."""
    labels = [tolerance_label(t) for t in cfg.tolerances()]
    header = TABLE_COLUMNS[:5] + [f"success@{l} [%]" for l in labels] + [f"reach@{l} [%]" for l in labels] \
        + TABLE_COLUMNS[7:]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for planner, split, m in rows:
        cells = [planner, split, str(m.get("problems", 0)),
                 _pm(m.get("solution_time_mean"), m.get("solution_time_std")),
                 _pm(m.get("path_length_mean"), m.get("path_length_std"), digits=2),
                 *[_pct(m.get(f"success_rate@{l}")) for l in labels], *[_pct(m.get(f"reach_rate@{l}")) for l in labels],
                 _pct(m.get("collision_rate")), _pct(m.get("self_collision_rate")), _pct(m.get("joint_limit_rate")),
                 _pm(m.get("inference_time_mean"), m.get("inference_time_std"), scale=1e3, digits=2)]
        lines.append("| " + " | ".join(cells) + " |")
    note = (f"Reached: end-effector within {labels[0]} and {cfg.orientation_tolerance:g} deg at the end of the rollout "
            f"(which stops at {labels[0]}); success: reached with no collision, self-collision or joint-limit violation. "
            "Path length: mean ± std over successful problems; times over all problems.")
    return "\n".join(lines) + "\n\n" + note + "\n"
