"""The MPiNet-style policy's LightningModule and its rollout adapter.

Training step, for a batch of (q_t + noise, q_{t+1}, q_goal, scene) from the same DataModule as SAMP:
  1. the labelled cloud: arm surface points at q_t, the scene's cached obstacle points, gripper surface
     points at the goal end-effector pose (the gripper posed by q_goal);
  2. q^_{t+1} = denormalize(MPiNetNet(normalize(q_t), cloud));
  3. L = w_match L_match + w_coll L_hinge, with L_match exactly SAMP's (all M robot points) and
     L_hinge = mean_i max(0, margin - C_i) over the robot's innermost-shell points at q^_{t+1}, C_i the
     environment SDF trilinear from the dataset's anchor grid (MPiNet: margin 0.03 m, weight 5).
No robot SDF and no per-point weights: MPiNet's collision loss is a plain hinge.
"""

from __future__ import annotations

import torch

from samp.policy.baselines.mpinet import MPiNetConfig, MPiNetNet, labelled_cloud, surface_points
from samp.policy.baselines.mpinet_points import SurfacePoints, gripper_links
from samp.names import BATCH_GOAL, BATCH_NEXT, BATCH_Q, BATCH_SCENE
from samp.policy.base import PolicySystemBase
from samp.policy.losses import match_loss
from samp.policy.network import denormalize, normalize, sample_by_scene
from samp.policy.plan import Plannable

__all__ = ["MPiNetStepPolicy", "MPiNetSystem", "hinge_collision_loss", "scene_obstacle_points"]


def hinge_collision_loss(points: torch.Tensor, grids: torch.Tensor, scene_index: torch.Tensor, bounds,
                         margin: float) -> torch.Tensor:
    """points (B, K, 3); grids (S, n, n, n) and scene_index (B,) into them -> mean max(0, margin - sdf)."""
    env = sample_by_scene(grids[:, None], scene_index, points, bounds)[:, 0]  # (B, K)
    return torch.relu(margin - env).mean()


def scene_obstacle_points(grids: torch.Tensor, bounds, count: int, seed: int) -> torch.Tensor:
    """(S, n, n, n) grids -> (S, count, 3) surface points per scene (`surface_points`), same seed for each."""
    bounds = [list(map(float, b)) for b in (bounds.tolist() if torch.is_tensor(bounds) else bounds)]
    return torch.stack([surface_points(g, bounds, count, seed) for g in grids])


class MPiNetSystem(PolicySystemBase, kind="mpinet"):
    """Args:
        robot: robot name (conf/robot/). model: MPiNetConfig fields (dof comes from the robot).
        match_weight, collision_weight: loss weights (MPiNet: 1 and 5). margin: hinge margin (metres).
        optimizer, scheduler: `_partial_` config nodes (conf/optimizer/), see `PolicySystemBase`.
    """

    def __init__(self, robot: str = "panda", model: dict | None = None, match_weight: float = 1.0,
                 collision_weight: float = 5.0, margin: float = 0.03, optimizer: dict | None = None,
                 scheduler: dict | None = None):
        super().__init__(robot, optimizer, scheduler)
        self.save_hyperparameters()
        self.net_cfg = MPiNetConfig(**{**(model or {}), "dof": self.robot.dof})
        self.net = MPiNetNet(self.net_cfg)
        shells = self.robot.point_shells
        inner = (shells == shells.min()).nonzero()[:, 0]  # points 1 mm outside the links: the robot's surface
        self.register_buffer("surface_index", inner, persistent=False)
        c = self.net_cfg
        self.robot_surface = SurfacePoints(self.robot, self.robot.point_link_names, c.robot_points, c.robot_seed)
        self.target_surface = SurfacePoints(self.robot, gripper_links(self.robot), c.target_points, c.robot_seed + 1)
        self.obstacles = None

    def _bound(self, binding) -> None:
        self.obstacles = self.obstacle_points(self.grids, self.bounds)

    def obstacle_points(self, grids: torch.Tensor, bounds) -> torch.Tensor:
        """(S, n, n, n) -> (S, N_o, 3) the obstacle part of each scene's cloud."""
        c = self.net_cfg
        return scene_obstacle_points(grids, bounds, c.obstacle_points, c.obstacle_seed).to(grids.dtype)

    def predict(self, q: torch.Tensor, q_goal: torch.Tensor, obstacles: torch.Tensor) -> torch.Tensor:
        """One step: q, q_goal (B, n) radians, obstacles (B, N_o, 3) -> q_next (B, n) radians."""
        with torch.no_grad():
            robot = self.robot_surface(self.robot.link_poses(q))  # (B, N_r, 3)
            target = self.target_surface(self.robot.link_poses(q_goal))  # (B, N_t, 3): the gripper at the goal
        xyz, labels = labelled_cloud(robot, obstacles.to(robot.dtype), target)
        u_g = normalize(q_goal, self.limits)
        return denormalize(self.net(normalize(q, self.limits), xyz, labels, u_g), self.limits)

    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        q, q_next, scene = batch[BATCH_Q], batch[BATCH_NEXT], batch[BATCH_SCENE]
        q_hat = self.predict(q, batch[BATCH_GOAL], self.obstacles[scene])
        pred = self.robot.transform_points(q_hat)  # (B, M, 3)
        with torch.no_grad():
            true = self.robot.transform_points(q_next)
        out = {"match": match_loss(pred, true),
               "coll": hinge_collision_loss(pred[:, self.surface_index], self.grids, scene, self.bounds,
                                            self.hparams.margin)}
        out["loss"] = self.hparams.match_weight * out["match"] + self.hparams.collision_weight * out["coll"]
        return out

    def planner(self, **options) -> "MPiNetStepPolicy":
        if options:
            raise ValueError(f"the mpinet policy takes no options, got {sorted(options)}")
        return MPiNetStepPolicy(self)


class MPiNetStepPolicy(Plannable):
    """A trained `MPiNetSystem` as a `StepPolicy` (samp.policy.interface): `reset` turns the batch's grids into obstacle
    points once (timed, like SAMP's grid encoding), `step` predicts q_{t+1}."""

    def __init__(self, system: MPiNetSystem, name: str = "mpinet"):
        system.fitted()
        self.system, self.robot, self.name, self.n_e = system, system.robot, name, system.n_e
        self._obstacles = None

    def reset(self, env) -> None:
        self.system.check_env(env)
        with torch.no_grad():
            self._obstacles = self.system.obstacle_points(env.grids.to(self.system.device, torch.float32),
                                                          self.system.bounds)

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env) -> torch.Tensor:
        if self._obstacles is None:
            self.reset(env)
        with torch.no_grad():
            return self.system.predict(q, q_goal, self._obstacles[env.scene_index])
