"""The SAMP policy's LightningModule: SAMPNet, the frozen robot SDF and the losses (docs/design.md section 4).

Training step, for a batch of (q_t + noise, q_{t+1}, q_goal, scene):
  1. pose the robot points at q_t, T_{q_t}(P), and query the frozen robot SDF there (no gradients);
  2. encode each distinct scene's grid once and predict q^_{t+1} (SAMPNet);
  3. L_match on T_{q^}(P) vs T_{q_{t+1}}(P), L_coll with the environment grid at T_{q^}(P) and
     per-point weights from the robot SDF at the prediction (radians), L_config on the joints.
Every loss is logged on its own (`train/match`, `train/coll`, `train/config`, `train/loss`, and `val/*`).
The rest (dataset binding, NaN stop, optimizer, checkpoint record) is `PolicySystemBase`'s.

The checkpoint holds everything needed to rebuild the policy: hyperparameters (architecture, losses,
optimizer), the dataset binding (robot, dataset id, n_e, bounds), the network and the robot SDF's
weights and description.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import torch

from samp.cli import paste
from samp.names import BATCH_GOAL, BATCH_NEXT, BATCH_Q, BATCH_SCENE
from samp.policy.base import NonFiniteLossError, PolicySystemBase
from samp.policy.losses import LossConfig, StepPrediction, loss_terms
from samp.policy.network import PolicyConfig, SAMPNet, denormalize, normalize

__all__ = ["NonFiniteLossError", "PolicySystem", "ROBOT_SDF_TABLES", "read_robot_sdf"]

# Joint angles per one-joint table of the robot SDF at the robot points (0: exact); see `PolicySystem`.
ROBOT_SDF_TABLES = 256
ROBOT_SDF_PAIRS = ("all", "near")

log = logging.getLogger(__name__)


def read_robot_sdf(ref: str | Path) -> dict:
    """A robot SDF artifact file or run folder -> the payload a policy keeps (description, weights, id).
    Names of experiments are resolved by the training recipe (`samp.train.prerequisites`), not here."""
    from samp.robot_sdf.artifact import _read, artifact_id

    path = Path(str(ref)).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"no robot SDF at {path}: give an artifact file (robot_sdf.pt) or the run folder of "
                                "a robot SDF training. By experiment name (robot_sdf_panda) it is resolved by "
                                "`python -m samp.train`, which also builds it when build_missing.robot_sdf=true")
    info, state, source = _read(path)
    return {"info": info, "state_dict": state, "artifact_id": artifact_id(source), "path": str(source)}


def _robot_sdf_from_payload(payload: dict, robot):
    """Rebuild the frozen robot SDF stored in a policy checkpoint (its description and weights)."""
    from samp.robot_sdf.artifact import build_net
    from samp.robot_sdf.whole_robot import RobotSDF

    info = payload["info"]
    if info["robot"] != robot.name or info["robot_asset_hash"] != robot.asset_hash:
        raise ValueError(f"the checkpoint's robot SDF is for robot {info['robot']!r} (assets "
                         f"{info['robot_asset_hash'][:12]}), not {robot.name!r} (assets {robot.asset_hash[:12]})")
    net = build_net(info["net"])
    net.load_state_dict(payload["state_dict"])
    return RobotSDF(robot, net, torch.tensor(info["centres"]), torch.tensor(info["scales"]), info.get("method", ""),
                    {"dataset_id": info.get("dataset_id"), "from": "policy checkpoint"})


class PolicySystem(PolicySystemBase, kind="samp"):
    """Args:
        robot: robot name (conf/robot/). robot_sdf: a robot SDF artifact file or run folder (the
            training recipe turns an experiment name into its newest completed run first).
        model: PolicyConfig fields (dof and num_points come from the robot). loss: LossConfig fields.
        collision_loss: False drops L_coll (ablation). robot_sdf_feature: False feeds zeros instead of
            the robot SDF values to the network (ablation); the collision weights still use it.
        robot_sdf_tables: K > 0 reads the robot SDF between a point and the next link along the chain
            from tables of K joint angles (`samp.robot_sdf.robot_points`, an approximation of the robot
            SDF network measured on the benchmark); 0 evaluates the network for every pair (exact).
        robot_sdf_pairs: the robot SDF input of the network at q_t, in training and in rollouts: "all" pairs
            of a point and a link (exact, up to the tables), or "near": only the pairs no arm joint or one arm
            joint apart (the rigid part and the tables), skipping the network for the rest, an approximation
            measured on the benchmark (docs/performance.md, "What a step costs" and "The training step").
            None (the default): "near" with tables, "all" without (robot_sdf_tables=0). The collision loss's
            weights at the prediction always use every pair.
        optimizer, scheduler: `_partial_` config nodes (conf/optimizer/), see `PolicySystemBase`.
        robot_sdf_payload: the robot SDF as a checkpoint stores it (instead of `robot_sdf`).
    """

    def __init__(self, robot: str = "panda", robot_sdf: str | None = None, model: dict | None = None,
                 loss: dict | None = None, collision_loss: bool = True, robot_sdf_feature: bool = True,
                 optimizer: dict | None = None, scheduler: dict | None = None, robot_sdf_payload: dict | None = None,
                 robot_sdf_tables: int = ROBOT_SDF_TABLES, robot_sdf_pairs: str | None = None):
        super().__init__(robot, optimizer, scheduler)
        self.save_hyperparameters(ignore=["robot_sdf_payload"])
        if robot_sdf_payload is None:  # a new policy: read the artifact the config names
            if robot_sdf is None:
                raise ValueError("the policy needs a robot SDF: set system.robot_sdf to an artifact, a run folder or "
                                 f"an experiment name (train one with `{paste('python -m samp.train', experiment=f'robot_sdf_{robot}')}`)")
            robot_sdf_payload = read_robot_sdf(robot_sdf)
        self._robot_sdf_payload = robot_sdf_payload
        self.robot_sdf = _robot_sdf_from_payload(robot_sdf_payload, self.robot)
        self.robot_sdf.requires_grad_(False).eval()
        self.robot_sdf_artifact_id = robot_sdf_payload.get("artifact_id")
        self.net_cfg = PolicyConfig(**{**(model or {}), "dof": self.robot.dof, "num_points": len(self.robot.points)})
        self.net = SAMPNet(self.net_cfg)
        self.loss_cfg = LossConfig(**(loss or {}))
        self.robot_sdf_tables = robot_sdf_tables
        self._set_pairs(robot_sdf_pairs)

    def _set_pairs(self, pairs: str | None) -> None:
        if pairs is None:  # the default: no network for far pairs where tables cover the near ones
            pairs = "near" if self.robot_sdf_tables >= 2 else "all"
        if pairs not in ROBOT_SDF_PAIRS:
            raise ValueError(f"robot_sdf_pairs must be one of {ROBOT_SDF_PAIRS}, got {pairs!r}")
        if pairs == "near" and self.robot_sdf_tables < 2:
            raise ValueError("robot_sdf_pairs=near reads the pairs one joint apart from tables: it needs "
                             f"robot_sdf_tables >= 2, got {self.robot_sdf_tables}")
        self.robot_sdf_pairs = pairs

    def train(self, mode: bool = True) -> "PolicySystem":
        super().train(mode)
        self.robot_sdf.eval()  # frozen: never in training mode
        return self

    # ------------------------------------------------------------------ the policy
    def robot_features(self, q: torch.Tensor, near: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """q (B, n) radians -> T_q(P) (B, M, 3) and the robot SDF there (B, M), no gradients; one FK for both.
        `near`: without the pairs two or more joints apart (what a rollout step asks for, `robot_sdf_pairs`)."""
        with torch.no_grad():
            poses = self.robot.link_poses(q)
            points = self.robot.transform_points(q, poses)
            return points, self.robot_sdf.at_robot_points(q, points, poses, self.robot_sdf_tables,
                                                          needed=False if near else None)

    def encode(self, grids: torch.Tensor) -> torch.Tensor | None:
        """(S, n_e, n_e, n_e) grids -> the env encoder's feature volumes (None without the env branch)."""
        return self.net.encode_scenes(grids) if self.net_cfg.env_encoder else None

    def predict(self, q: torch.Tensor, q_goal: torch.Tensor, features: torch.Tensor | None, scene: torch.Tensor,
                bounds, near: bool = False) -> torch.Tensor:
        """One policy step: q, q_goal (B, n) radians; features from `encode`, scene (B,) into them -> (B, n).
        `near`: the robot SDF input without the far pairs (`robot_features`); the losses always use them all."""
        points, d_robot = self.robot_features(q, near)
        if not self.hparams.robot_sdf_feature:
            d_robot = torch.zeros_like(d_robot)
        u = self.net(normalize(q, self.limits), normalize(q_goal, self.limits), points, d_robot, features, scene, bounds,
                     n_e=self.n_e)
        return denormalize(u, self.limits)

    def planner(self, robot_sdf_tables: int | None = None, check: int | dict | None = None,
                robot_sdf_pairs: str | None = None, compiled: bool | None = None, stride: float = 1.0,
                **options):
        """The current weights as a `StepPolicy` (`SAMPStepPolicy`), for rollouts and `EvalCallback`.
        `robot_sdf_tables` replaces the system's own (0: the exact robot SDF at the robot points);
        `robot_sdf_pairs` likewise ("all" | "near", see the class). `compiled`: the step's inputs in one
        compiled call on a CPU (`SAMPStepPolicy`; None: wherever the system allows it, False: the torch path).
        `check`: a number of candidates, or `CheckConfig` fields, gives the checked planner instead
        (`samp.policy.checked.CheckedPolicy`, "samp+check", a `TrajectoryPlanner`). `stride`: each step moves
        up to that many times the predicted step, less near the goal (`SAMPStepPolicy`)."""
        from samp.policy.step import SAMPStepPolicy

        if options:
            raise ValueError("the samp policy takes only robot_sdf_tables, robot_sdf_pairs, compiled, check and "
                             f"stride as planner options, got {sorted(options)}")
        if robot_sdf_tables is not None:
            if not isinstance(robot_sdf_tables, int) or robot_sdf_tables < 0 or robot_sdf_tables == 1:
                raise ValueError(f"robot_sdf_tables must be 0 (exact) or an integer >= 2, got {robot_sdf_tables!r}")
            self.robot_sdf_tables = robot_sdf_tables
        if robot_sdf_pairs is not None or robot_sdf_tables is not None:  # new tables alone: their default pairs
            self._set_pairs(robot_sdf_pairs)
        if check is None:
            return SAMPStepPolicy(self, compiled=compiled, stride=stride)
        if stride != 1.0:
            raise ValueError("stride applies to the plain policy; samp+check (check=...) steps as trained")
        from samp.policy.checked import CheckConfig, CheckedPolicy

        config = CheckConfig(**check) if isinstance(check, dict) else CheckConfig(candidates=check)
        return CheckedPolicy(SAMPStepPolicy(self, compiled=compiled), config)

    # ------------------------------------------------------------------ training
    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        q, q_next, scene = batch[BATCH_Q], batch[BATCH_NEXT], batch[BATCH_SCENE]
        present, local = scene.unique(return_inverse=True)  # each distinct scene is encoded once
        q_hat = self.predict(q, batch[BATCH_GOAL], self.encode(self.grids[present]), local, self.bounds,
                             near=self.robot_sdf_pairs == "near")
        poses = self.robot.link_poses(q_hat)
        pred_points = self.robot.transform_points(q_hat, poses)
        with torch.no_grad():
            true_points = self.robot.transform_points(q_next)
        step = StepPrediction(q_hat, q_next, pred_points, true_points, self.grids, scene, self.bounds,
                              robot_sdf=lambda needed: self.robot_sdf.at_robot_points(
                                  q_hat.detach(), pred_points.detach(), poses.detach(), self.robot_sdf_tables, needed))
        return loss_terms(step, self.loss_cfg, off=() if self.hparams.collision_loss else ("coll",))

    # ------------------------------------------------------------------ checkpoints
    def _checkpoint_extra(self) -> dict:
        return {"robot_sdf": self._robot_sdf_payload, "net": asdict(self.net_cfg), "loss": asdict(self.loss_cfg),
                "robot_sdf_artifact_id": self.robot_sdf_artifact_id}

    @classmethod
    def _build(cls, hparams: dict, record: dict) -> "PolicySystem":
        if not record.get("robot_sdf"):
            raise ValueError("the samp checkpoint carries no robot SDF (its record has no robot_sdf payload)")
        net = record.get("net") or {}
        if "registration" not in net:  # trained before feature cells were placed at their centres
            hparams["model"] = {**(hparams.get("model") or {}), "registration": "bounds"}
            log.info("this policy checkpoint predates feature registration at cell centres: its feature volume is "
                     "read over the grid's bounds, as it was trained (model.registration=bounds)")
        if "norm" not in net:  # trained when BatchNorm was the only normalisation
            hparams["model"] = {**(hparams.get("model") or {}), "norm": "batch"}
        return cls(**hparams, robot_sdf_payload=record["robot_sdf"])
