"""`robot` suite: FK and transform_points for B in --batch; baseline: pybullet FK, one configuration at a time."""

from __future__ import annotations

import argparse

import numpy as np
import torch

from .common import timeit


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 50, 1024])


def _pybullet_arm(model) -> tuple[int, int, list[int], list[int]]:
    """The robot's URDF in a DIRECT pybullet client: (client, body, the arm's joint indices in samp's joint order,
    every link index)."""
    import pybullet as pb

    client = pb.connect(pb.DIRECT)
    body = pb.loadURDF(str(model.urdf.path), useFixedBase=True, physicsClientId=client)
    joint_index = {pb.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
                   for j in range(pb.getNumJoints(body, physicsClientId=client))}
    arm = [joint_index[name] for name in model.joint_names]
    all_links = list(range(pb.getNumJoints(body, physicsClientId=client)))
    return client, body, arm, all_links


def run(args) -> tuple[dict, list[list]]:
    import pybullet as pb

    from samp.robot import load_robot

    device = torch.device(args.device)
    model = load_robot(args.robot, dtype=torch.float32).to(device)
    lo, hi = model.joint_limits.T.cpu().numpy()
    client, body, arm, all_links = _pybullet_arm(model)

    metrics, rows = {}, []
    for B in args.batch:
        q_np = np.random.default_rng(0).uniform(lo, hi, size=(B, model.dof))
        q = torch.as_tensor(q_np, dtype=torch.float32, device=device)

        def pybullet_fk():
            for qi in q_np:
                for j, v in zip(arm, qi):
                    pb.resetJointState(body, j, v, physicsClientId=client)
                pb.getLinkStates(body, all_links, computeForwardKinematics=True, physicsClientId=client)

        with torch.no_grad():
            t_pb = timeit(pybullet_fk, torch.device("cpu"))
            t_fk = timeit(lambda: model.fk(q), device)
            t_tp = timeit(lambda: model.transform_points(q), device)
        metrics.update({f"B{B}/pybullet_fk_ms": 1e3 * t_pb, f"B{B}/fk_ms": 1e3 * t_fk,
                        f"B{B}/transform_points_ms": 1e3 * t_tp, f"B{B}/fk_speedup": t_pb / t_fk,
                        f"B{B}/transform_points_speedup": t_pb / t_tp})
        rows.append([B, f"{1e3 * t_pb:.3f}", f"{1e3 * t_fk:.3f}", f"{t_pb / t_fk:.2f}x",
                     f"{1e3 * t_tp:.3f}", f"{t_pb / t_tp:.2f}x"])
    pb.disconnect(client)
    header = ["B", "pybullet FK [ms]", "samp fk [ms]", "fk vs pybullet", "transform_points [ms]", "tp vs pybullet"]
    return metrics, [header, *rows]
