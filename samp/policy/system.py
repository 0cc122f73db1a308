"""The policy's LightningModule: SAMPNet, the frozen robot SDF, the losses, AdamW with warm restarts.

Training step, for a batch of (q_t + noise, q_{t+1}, q_goal, scene):
  1. pose the robot points at q_t, T_{q_t}(P), and query the frozen robot SDF there (no gradients);
  2. encode each distinct scene's grid once and predict q^_{t+1} (SAMPNet);
  3. L_match on T_{q^}(P) vs T_{q_{t+1}}(P), L_coll with the environment grid at T_{q^}(P) and
     per-point weights from the robot SDF at the prediction (radians), L_config on the joints.
Every loss is logged on its own (`train/match`, `train/coll`, `train/config`, `train/loss`, and `val/*`).
A non-finite loss stops training with a message (`NonFiniteLossError`); the last good checkpoint stays.

The checkpoint holds everything needed to rebuild the policy: hyperparameters (robot, dataset id, n_e,
bounds, architecture), the network and the robot SDF's weights and configuration.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import pytorch_lightning as pl
import torch

from samp.policy.losses import LossConfig, collision_loss, config_loss, match_loss
from samp.policy.network import PolicyConfig, SAMPNet, denormalize, normalize

__all__ = ["NonFiniteLossError", "PolicySystem", "adamw_warm_restarts", "bind_dataset", "check_finite"]


class NonFiniteLossError(FloatingPointError):
    """Training produced a NaN or infinite loss (`samp.train` exits 1 with this message)."""


def bind_dataset(system: pl.LightningModule, dm, label: str) -> None:
    """At fit start: refuse a DataModule of another robot, then take its n_e, bounds, dataset id and
    grids into `system` (the hyperparameters saved with the weights). `label` names the model in errors."""
    if dm.robot_name != system.hparams.robot or dm.robot_asset_hash != system.robot.asset_hash:
        raise ValueError(f"dataset {dm.dataset_id} is for robot {dm.robot_name!r}; the {label} is for "
                         f"{system.hparams.robot!r}: use a dataset generated for this robot")
    system.hparams.n_e, system.hparams.bounds, system.hparams.dataset_id = dm.n_e, dm.bounds, dm.dataset_id
    system.grids = dm.grids.to(system.device)


def check_finite(system: pl.LightningModule, losses: dict[str, torch.Tensor], label: str) -> None:
    """Stop training with `NonFiniteLossError` when `losses["loss"]` is NaN or infinite."""
    if torch.isfinite(losses["loss"]):
        return
    parts = ", ".join(f"{k} {v.item():.4g}" for k, v in losses.items() if k != "loss")
    raise NonFiniteLossError(
        f"{label} training loss is {losses['loss'].item()} at epoch {system.current_epoch}, step "
        f"{system.global_step} ({parts}); the last good checkpoint is kept in the run's checkpoints/. "
        "Lower the learning rate or check the dataset (`python -m samp.data verify`)")


def adamw_warm_restarts(system: pl.LightningModule, params) -> dict:
    """AdamW with cosine warm restarts from `system.hparams` (lr, weight_decay, restart_epochs, restart_mult)."""
    h = system.hparams
    opt = torch.optim.AdamW(params, lr=h.lr, weight_decay=h.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(opt, T_0=h.restart_epochs, T_mult=h.restart_mult)
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}


def resolve_robot_sdf(ref: str, runs_dir: str | Path | None = None) -> Path:
    """A robot SDF reference -> its artifact or run folder: an existing path, or an experiment name
    under the runs folder (its newest completed run that wrote `robot_sdf.pt`)."""
    from samp.robot_sdf.artifact import ARTIFACT_FILE
    from samp.runs import RunFolder, runs_root

    path = Path(ref).expanduser()
    if path.exists():
        return path
    folder = Path(runs_dir) if runs_dir else runs_root()
    folder = folder if folder.is_absolute() else Path(__file__).resolve().parents[2] / folder
    for run in sorted((folder / str(ref)).glob("*/"), reverse=True):
        if (run / ARTIFACT_FILE).is_file() and RunFolder(run).read().get("status") == "completed":
            return run
    robot = str(ref).removeprefix("robot_sdf_") or "panda"
    raise FileNotFoundError(f"no robot SDF {ref!r}: not a file or folder, and no completed run with {ARTIFACT_FILE} "
                            f"under {folder / str(ref)}. Train one with `python -m samp.train "
                            f"+experiment=robot_sdf_{robot}` or set system.robot_sdf to a run folder or artifact")


def _buildable(ref: str, robot: str) -> bool:
    """Whether `ref` names a robot SDF experiment of `robot` in conf/experiment/ (robot_sdf_<robot>[_...])."""
    from samp.paths import conf_dir

    return ref.startswith(f"robot_sdf_{robot}") and (conf_dir() / "experiment" / f"{ref}.yaml").is_file()


def _build_robot_sdf(experiment: str, runs_dir: str | Path | None, extra: list[str] = ()) -> Path:
    """Train the robot SDF experiment `experiment` (its own run folder, `extra` overrides) and return that folder."""
    from samp.train import train

    overrides = [f"+experiment={experiment}", *([f"paths.runs_dir={runs_dir}"] if runs_dir else []), *extra]
    print(f"robot SDF {experiment!r} is not trained yet: running {' '.join(overrides)}", flush=True)
    return train(overrides).path


def _robot_sdf_from_payload(payload: dict, robot):
    """Rebuild the frozen robot SDF stored in a policy checkpoint (its description and weights)."""
    from samp.robot_sdf.artifact import build_net
    from samp.robot_sdf.query import RobotSDF

    info = payload["info"]
    if info["robot"] != robot.name or info["robot_asset_hash"] != robot.asset_hash:
        raise ValueError(f"the checkpoint's robot SDF is for robot {info['robot']!r} (assets "
                         f"{info['robot_asset_hash'][:12]}), not {robot.name!r} (assets {robot.asset_hash[:12]})")
    net = build_net(info["net"])
    net.load_state_dict(payload["state_dict"])
    return RobotSDF(robot, net, torch.tensor(info["centres"]), torch.tensor(info["scales"]), info.get("method", ""),
                    {"dataset_id": info.get("dataset_id"), "from": "policy checkpoint"})


class PolicySystem(pl.LightningModule):
    """Args:
        robot: robot name (conf/robot/). robot_sdf: a robot SDF reference (`samp.robot_sdf.load_robot_sdf`).
        model: PolicyConfig fields (dof and num_points come from the robot). loss: LossConfig fields.
        collision_loss: False drops L_coll (ablation). robot_sdf_feature: False feeds zeros instead of
            the robot SDF values to the network (ablation); the collision weights still use it.
        runs_dir: where a robot SDF given as an experiment name is looked up (default: runs/).
        build_robot_sdf: when `robot_sdf` names a robot SDF experiment of this robot (conf/experiment/
            robot_sdf_<robot>*.yaml) and no completed run of it exists, train it first (with
            `build_overrides`, e.g. ["robot_sdf_samples=tiny"]).
        eval_problems: problems per split for the evaluation after training (`evaluate_run`); 0: none.
        lr, weight_decay: AdamW. restart_epochs, restart_mult: CosineAnnealingWarmRestarts T_0, T_mult.
        n_e, bounds, dataset_id: filled in from the DataModule at fit time and saved with the weights.
    """

    def __init__(self, robot: str = "panda", robot_sdf: str | None = None, model: dict | None = None,
                 loss: dict | None = None, collision_loss: bool = True, robot_sdf_feature: bool = True,
                 lr: float = 1e-4, weight_decay: float = 1e-2, restart_epochs: int = 10, restart_mult: int = 2,
                 runs_dir: str | None = None, build_robot_sdf: bool = False, build_overrides: list | None = None,
                 eval_problems: int = 50, n_e: int | None = None, bounds=None, dataset_id: str | None = None,
                 robot_sdf_payload: dict | None = None):
        super().__init__()
        from samp.robot import load_robot
        from samp.robot_sdf.artifact import _read, artifact_id

        self.save_hyperparameters(ignore=["robot_sdf_payload", "build_overrides"])
        self.robot = load_robot(robot)
        self.robot.requires_grad_(False)
        if robot_sdf_payload is None:  # a new policy: read the artifact the config names
            if robot_sdf is None:
                raise ValueError("the policy needs a robot SDF: set system.robot_sdf to an artifact, a run folder or "
                                 f"an experiment name (train one with `python -m samp.train +experiment=robot_sdf_{robot}`)")
            try:
                source = resolve_robot_sdf(robot_sdf, runs_dir)
            except FileNotFoundError:
                if not (build_robot_sdf and _buildable(robot_sdf, robot)):
                    raise
                source = _build_robot_sdf(robot_sdf, runs_dir, list(build_overrides or []))
            info, state, path = _read(source)
            robot_sdf_payload = {"info": info, "state_dict": state, "artifact_id": artifact_id(path), "path": str(path)}
        self._robot_sdf_payload = robot_sdf_payload
        self.robot_sdf = _robot_sdf_from_payload(robot_sdf_payload, self.robot)
        self.robot_sdf.requires_grad_(False).eval()
        self.robot_sdf_artifact_id = robot_sdf_payload.get("artifact_id")
        self.net_cfg = PolicyConfig(**{**(model or {}), "dof": self.robot.dof, "num_points": len(self.robot.points)})
        self.net = SAMPNet(self.net_cfg)
        self.loss_cfg = LossConfig(**(loss or {}))

    def to(self, *args, **kwargs) -> "PolicySystem":
        """Also moves the robot's kinematic chain (which `nn.Module.to` alone would not)."""
        super().to(*args, **kwargs)
        self.robot.to(*args, **kwargs)
        return self

    def train(self, mode: bool = True) -> "PolicySystem":
        super().train(mode)
        self.robot_sdf.eval()  # frozen: never in training mode
        return self

    # ------------------------------------------------------------------ shared pieces
    @property
    def limits(self) -> torch.Tensor:
        return self.robot.joint_limits.to(self.device, torch.float32)

    def on_fit_start(self) -> None:
        bind_dataset(self, self.trainer.datamodule, "policy")

    def robot_features(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """q (B, n) radians -> T_q(P) (B, M, 3) and the robot SDF there (B, M), no gradients."""
        with torch.no_grad():
            points = self.robot.transform_points(q)
            return points, self.robot_sdf.query(points, q)

    def encode(self, grids: torch.Tensor) -> torch.Tensor | None:
        """(S, n_e, n_e, n_e) grids -> the env encoder's feature volumes (None without the env branch)."""
        return self.net.encode_scenes(grids) if self.net_cfg.env_encoder else None

    def predict(self, q: torch.Tensor, q_goal: torch.Tensor, features: torch.Tensor | None, scene: torch.Tensor,
                bounds) -> torch.Tensor:
        """One policy step: q, q_goal (B, n) radians; features from `encode`, scene (B,) into them -> (B, n)."""
        points, d_robot = self.robot_features(q)
        if not self.hparams.robot_sdf_feature:
            d_robot = torch.zeros_like(d_robot)
        u = self.net(normalize(q, self.limits), normalize(q_goal, self.limits), points, d_robot, features, scene, bounds)
        return denormalize(u, self.limits)

    def step_policy(self):
        """The current weights as a `samp.eval.StepPolicy` (for rollouts and `EvalCallback`)."""
        from samp.policy.step import SAMPStepPolicy

        return SAMPStepPolicy(self)

    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        q, q_next, scene = batch["q"], batch["q_next"], batch["scene"]
        present, local = scene.unique(return_inverse=True)  # each distinct scene is encoded once
        q_hat = self.predict(q, batch["q_goal"], self.encode(self.grids[present]), local, self.hparams.bounds)
        pred_points = self.robot.transform_points(q_hat)
        with torch.no_grad():
            true_points = self.robot.transform_points(q_next)
        out = {"match": match_loss(pred_points, true_points), "config": config_loss(q_hat, q_next)}
        if self.hparams.collision_loss:
            d_pred = self.robot_sdf.query(pred_points.detach(), q_hat.detach())  # radians, per point
            out["coll"] = collision_loss(pred_points, self.grids, scene, self.hparams.bounds, d_pred, self.loss_cfg)
        else:
            out["coll"] = torch.zeros((), device=q.device)
        c = self.loss_cfg
        out["loss"] = c.match * out["match"] + c.collision * out["coll"] + c.config * out["config"]
        return out

    # ------------------------------------------------------------------ Lightning hooks
    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        losses = self._losses(batch)
        check_finite(self, losses, "policy")
        self.log_dict({f"train/{k}": v for k, v in losses.items()}, prog_bar=False, batch_size=len(batch["q"]))
        self.log("loss", losses["loss"], prog_bar=True, logger=False, batch_size=len(batch["q"]))
        return losses["loss"]

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        losses = self._losses(batch)
        self.log_dict({f"val/{k}": v for k, v in losses.items()}, prog_bar=False, batch_size=len(batch["q"]))

    def configure_optimizers(self):
        return adamw_warm_restarts(self, self.net.parameters())

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["robot_sdf_payload"] = self._robot_sdf_payload
        checkpoint["policy"] = {"net": asdict(self.net_cfg), "loss": asdict(self.loss_cfg), "robot": self.robot.name,
                                "robot_asset_hash": self.robot.asset_hash, "n_e": self.hparams.n_e,
                                "bounds": self.hparams.bounds, "dataset_id": self.hparams.dataset_id,
                                "robot_sdf_artifact_id": self.robot_sdf_artifact_id}

    def evaluate_run(self, run_dir: str | Path) -> dict:
        """After training (`samp.train`): roll the final policy out on training and held-out problems,
        beside the expert and the straight-line baseline; writes `<run>/eval/` and `<run>/plots/summary.png`
        and returns flat metrics."""
        if not self.hparams.eval_problems:
            return {}
        from samp.eval.__main__ import evaluate_trained

        dm = self.trainer.datamodule if self._trainer is not None else None
        return evaluate_trained(run_dir, "samp", self.hparams.eval_problems, dm.root if dm is not None else None)

    @classmethod
    def from_checkpoint(cls, path: str | Path, map_location="cpu") -> "PolicySystem":
        """Rebuild a trained policy from its checkpoint alone (the robot SDF travels inside it)."""
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
        if "robot_sdf_payload" not in ckpt or "policy" not in ckpt:
            raise ValueError(f"{path} is not a SAMP policy checkpoint (no robot SDF or policy record inside)")
        hparams = dict(ckpt["hyper_parameters"])
        if "goal_features" not in ckpt["policy"]["net"]:  # saved before goal features existed: the paper's MLP_I
            hparams["model"] = {**(hparams.get("model") or {}), "goal_features": False}
        system = cls(**hparams, robot_sdf_payload=ckpt["robot_sdf_payload"])
        system.load_state_dict(ckpt["state_dict"])
        return system.eval()
