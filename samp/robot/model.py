"""`Robot`: kinematics, link geometry and robot points of one arm, as a torch module.

FK runs through pytorch-kinematics on the URDF's joint tree. The module's buffers (limits, points) and
the kinematic chain move together with `.to(device, dtype)`; float32 and float64 both work.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytorch_kinematics as pk
import torch
from torch import nn

from samp.paths import cache_dir, file_sha256, resolve_asset, write_cache_file
from samp.robot.config import RobotConfig, load_robot_config
from samp.robot.geometry import LinkGeometry, link_geometry
from samp.robot.points import sample_shell_points
from samp.robot.serial import SerialFK
from samp.robot.urdf import URDFModel, parse_urdf

__all__ = ["Robot", "load_robot"]

POINTS_FORMAT = "shell-points-v1"  # bump when the sampling algorithm changes, to invalidate caches


def load_robot(name_or_path, *, dtype: torch.dtype = torch.float32) -> "Robot":
    """Load a robot by name (`conf/robot/NAME.yaml`), YAML path or config mapping."""
    return Robot(load_robot_config(name_or_path)).to(dtype)


class Robot(nn.Module):
    """One robot arm.

    Attributes:
        joint_names: (n,) arm joints, the columns of q.
        joint_limits: (n, 2) buffer, radians, float64 whatever the robot's dtype (exact config values).
        points: (M, 3) buffer, robot points in their link frames.
        point_links: (M,) buffer, index into `point_link_names`.
        point_shells: (M,) buffer, index into `cfg.points.offsets`.
        link_meshes: link name -> trimesh.Trimesh in the link frame (convex parts, welded).
    """

    def __init__(self, cfg: RobotConfig):
        super().__init__()
        self.cfg = cfg
        self.name = cfg.name
        urdf_path = resolve_asset(cfg.urdf, Path(cfg.source_dir) if cfg.source_dir else None)
        self.urdf: URDFModel = parse_urdf(urdf_path)
        self._validate_against_urdf()
        self.joint_names = list(cfg.joints)
        self.base_link, self.ee_link = cfg.base_link, cfg.ee_link
        self.link_names = list(cfg.collision_links)
        self.point_link_names = list(cfg.point_links)
        self.self_collision_exclude = [tuple(p) for p in cfg.self_collision_exclude]
        self.geometry: dict[str, LinkGeometry] = {
            name: link_geometry(name, self.urdf.collisions[name]) for name in self.link_names
        }
        self.asset_hash = self._asset_hash()

        self.chain = pk.build_chain_from_urdf(self.urdf.kinematic_xml)
        chain_joints = self.chain.get_joint_parameter_names()
        held = {j: 0.0 for j in chain_joints if j not in self.joint_names}
        held.update({j: cfg.gripper.opening for j in cfg.gripper.joints})
        self.register_buffer("_arm_index", torch.tensor([chain_joints.index(j) for j in self.joint_names]))
        self.register_buffer("_held_index", torch.tensor([chain_joints.index(j) for j in held], dtype=torch.long))
        self.register_buffer("_held_value", torch.tensor(list(held.values()), dtype=torch.float64))
        self.register_buffer("joint_limits", torch.tensor([cfg.lower, cfg.upper], dtype=torch.float64).T.contiguous())
        self.register_buffer("home", torch.tensor(cfg.home, dtype=torch.float64))
        self._exact = _exact_chain_constants(self.chain, self.urdf)
        self.chain = self._set_chain(dtype=torch.float64, device=torch.device("cpu"))
        self._frame = {name: idx for idx, name in self.chain.idx_to_frame.items()}
        base_pose = self._fk_raw(self.home[None])[self._frame[self.base_link], 0]
        self._base_is_root = bool(torch.equal(base_pose, torch.eye(4, dtype=base_pose.dtype)))
        self.register_buffer("_base_inv", torch.linalg.inv(base_pose))
        try:  # link poses in a few products for a serial arm (samp.robot.serial); else the general FK
            self._serial = SerialFK(self.urdf, self.joint_names, self.link_names, held, self._base_inv.numpy())
        except ValueError:
            self._serial = None
        self._held = held
        self._frame_fks: dict[tuple[str, ...], SerialFK | None] = {}  # `frames_fk`

        points, links, shells = self._robot_points()
        self.register_buffer("points", torch.from_numpy(points))
        self.register_buffer("point_links", torch.from_numpy(links).long())
        self.register_buffer("point_shells", torch.from_numpy(shells).long())
        # Derived from the config (not saved with a model): the chain frames of the collision links, and which
        # collision link (index into link_names) carries each point (the robot SDF's own-link pairs).
        self.register_buffer("_link_frames", torch.tensor([self._frame[n] for n in self.link_names]), persistent=False)
        self.register_buffer("point_collision_links", torch.tensor(
            [self.link_names.index(self.point_link_names[i]) for i in links], dtype=torch.long), persistent=False)
        # Points are grouped by link: transform_points maps each link's contiguous run (index into link_names)
        # in one product.
        starts = np.searchsorted(links, np.arange(len(self.point_link_names) + 1))
        self._point_runs = [(self.link_names.index(self.point_link_names[li]), slice(int(a), int(b)))
                            for li, (a, b) in enumerate(zip(starts[:-1], starts[1:])) if b > a]

    # ----------------------------------------------------------------- validation and assets
    def _validate_against_urdf(self) -> None:
        urdf, cfg = self.urdf, self.cfg
        known = set(urdf.joints)
        for j in [*cfg.joints, *cfg.gripper.joints]:
            if j not in known:
                raise ValueError(f"robot {cfg.name!r}: joint {j!r} is not in {urdf.path.name}; "
                                 f"its joints are {sorted(known)}")
            if urdf.joints[j].type == "fixed":
                raise ValueError(f"robot {cfg.name!r}: joint {j!r} is fixed in {urdf.path.name}, it cannot be an arm joint")
        for link in {cfg.base_link, cfg.ee_link, *cfg.collision_links, *cfg.point_links,
                     *(l for pair in cfg.self_collision_exclude for l in pair)}:
            if link not in urdf.links:
                raise ValueError(f"robot {cfg.name!r}: link {link!r} is not in {urdf.path.name}; its links are {urdf.links}")
        for link in cfg.collision_links:
            if not urdf.collisions[link]:
                raise ValueError(f"robot {cfg.name!r}: collision link {link!r} has no <collision> geometry in "
                                 f"{urdf.path.name}; remove it from collision_links or add a collision mesh")
        stray = [l for l in cfg.point_links if l not in cfg.collision_links]
        if stray:
            raise ValueError(f"robot {cfg.name!r}: point_links {stray} must also be collision_links")
        for j, lo, hi in zip(cfg.joints, cfg.lower, cfg.upper):
            uj = urdf.joints[j]
            if uj.lower is not None and (lo < uj.lower - 1e-9 or hi > uj.upper + 1e-9):
                raise ValueError(f"robot {cfg.name!r}: limits [{lo}, {hi}] of {j!r} exceed the URDF's [{uj.lower}, {uj.upper}]")
        link = cfg.base_link
        while link != urdf.root:
            parent = urdf.parent_joint(link)
            if parent.type != "fixed":
                raise ValueError(f"robot {cfg.name!r}: base_link {cfg.base_link!r} moves with joint {parent.name!r}; "
                                 "the base must be fixed to the URDF root")
            link = parent.parent

    def _asset_hash(self) -> str:
        """sha256 over the URDF and every collision mesh file (names and contents)."""
        h = hashlib.sha256()
        for path in self.urdf.asset_files():
            h.update(path.name.encode())
            h.update(file_sha256(path).encode())
        return h.hexdigest()

    def _robot_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cfg = self.cfg
        key_src = json.dumps({"format": POINTS_FORMAT, "asset": self.asset_hash, "points": asdict(cfg.points),
                              "links": cfg.point_links, "collision_links": cfg.collision_links,
                              "home": cfg.home, "gripper": asdict(cfg.gripper)}, sort_keys=True)
        key = hashlib.sha256(key_src.encode()).hexdigest()[:16]
        path = cache_dir("robot_points") / f"{cfg.name}-{key}.npz"
        if path.is_file():
            with np.load(path) as z:
                return z["points"], z["links"], z["shells"]
        with torch.no_grad():
            fk = self._base_inv @ self._fk_raw(self.home[None])
        poses = {name: fk[self._frame[name], 0].numpy() for name in self.link_names}
        points, links, shells = sample_shell_points(self.geometry, self.point_link_names, poses, cfg.points)
        write_cache_file(path, lambda f: np.savez(f, points=points, links=links, shells=shells))
        return points, links, shells

    # ----------------------------------------------------------------- device and dtype
    def to(self, *args, **kwargs) -> "Robot":
        device, dtype, *_ = torch._C._nn._parse_to(*args, **kwargs)
        super().to(*args, **kwargs)
        self.chain = self._set_chain(dtype=dtype or self.chain.dtype, device=device or self.chain.device)
        if self._serial is not None:
            self._serial.to(self.chain.dtype, self.chain.device)
        # Limits and home stay float64 from the config: rounded to float32, a configuration exactly at a
        # limit (as expert goals often are) would read as outside it.
        self.joint_limits = torch.tensor([self.cfg.lower, self.cfg.upper], dtype=torch.float64,
                                         device=self.points.device).T.contiguous()
        self.home = torch.tensor(self.cfg.home, dtype=torch.float64, device=self.points.device)
        return self

    def _set_chain(self, dtype: torch.dtype, device) -> pk.Chain:
        """Move the chain, then restore its constant transforms from float64 masters, so a round trip
        through float32 loses nothing."""
        chain = self.chain.to(dtype=dtype, device=device)
        chain._static_offsets = self._exact["static_offsets"].to(dtype=dtype, device=device)
        chain.axes = self._exact["axes"].to(dtype=dtype, device=device)
        return chain

    @property
    def dtype(self) -> torch.dtype:
        return self.points.dtype

    @property
    def device(self) -> torch.device:
        return self.points.device

    @property
    def link_meshes(self):
        return {name: g.mesh for name, g in self.geometry.items()}

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    # ----------------------------------------------------------------- kinematics
    def _check_q(self, q: torch.Tensor) -> None:
        if not isinstance(q, torch.Tensor):
            raise TypeError(f"q must be a torch.Tensor of shape (B, {self.dof}), got {type(q).__name__}")
        if q.ndim != 2 or q.shape[1] != self.dof:
            raise ValueError(f"q must have shape (B, {self.dof}) for {self.name}'s joints {self.joint_names}, "
                             f"got {tuple(q.shape)}" + ("; use q[None] for one configuration" if q.ndim == 1 else ""))
        if q.dtype != self.dtype:
            raise TypeError(f"q has dtype {q.dtype} but the robot is {self.dtype}; call robot.to({q.dtype}) or q.to(robot.dtype)")

    def _full_q(self, q: torch.Tensor) -> torch.Tensor:
        """(B, n) arm joints -> (B, n_chain) with the held joints filled in."""
        full = q.new_zeros(q.shape[0], len(self._arm_index) + len(self._held_index))
        full = full.index_copy(1, self._arm_index, q)
        return full.index_copy(1, self._held_index, self._held_value.to(q.dtype).expand(q.shape[0], -1))

    def _fk_raw(self, q: torch.Tensor) -> torch.Tensor:
        """(B, n) -> (F, B, 4, 4) poses of all chain frames relative to the URDF root."""
        return self.chain.forward_kinematics_tensor(self._full_q(q))

    def _fk_base(self, q: torch.Tensor) -> torch.Tensor:
        """(B, n) -> (F, B, 4, 4) poses of all chain frames in the base frame."""
        self._check_q(q)
        T = self._fk_raw(q)
        return T if self._base_is_root else self._base_inv @ T

    def fk(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """q (B, n) radians -> link name -> (B, 4, 4) pose in the base frame, for every URDF link."""
        T = self._fk_base(q)
        return {name: T[idx] for name, idx in self._frame.items()}

    def link_poses(self, q: torch.Tensor) -> torch.Tensor:
        """q (B, n) radians -> (B, L, 4, 4) poses of the collision links (`link_names` order) in the base frame.

        One FK for everything a policy step needs: `transform_points(q, poses)` and the robot SDF
        (`RobotSDF.at_robot_points`) both take these instead of running FK again."""
        if self._serial is not None:
            self._check_q(q)
            return self._serial(q)
        return self._fk_base(q)[self._link_frames].transpose(0, 1)

    def frames_fk(self, frames: tuple[str, ...]):
        """A `SerialFK` for the URDF frames `frames` (e.g. the IK's joint frames and end effector) in the
        robot's dtype and device, or None when the arm is not serial for them; built once per tuple."""
        frames = tuple(frames)
        if frames not in self._frame_fks:
            try:
                self._frame_fks[frames] = SerialFK(self.urdf, self.joint_names, list(frames), self._held,
                                                   self._base_inv.double().cpu().numpy())
            except ValueError:
                self._frame_fks[frames] = None
        fk = self._frame_fks[frames]
        if fk is not None and (fk.A.dtype != self.dtype or fk.A.device != self.device):
            fk.to(self.dtype, self.device)
        return fk

    @property
    def serial_fk(self) -> SerialFK | None:
        """The collision links' `SerialFK` (float64 masters), or None when the arm is not serial for them."""
        return self._serial

    def link_poses_numpy(self, q: np.ndarray) -> np.ndarray:
        """q (B, n) float64 numpy -> (B, L, 4, 4) float64 numpy poses of the collision links, for the CPU
        collision checks (`samp.robot.bodies.LinkBodies`): the serial arm's numpy FK, or the general FK."""
        q = np.asarray(q, dtype=np.float64)
        if self._serial is not None:
            if q.ndim != 2 or q.shape[1] != self.dof:
                raise ValueError(f"q must have shape (B, {self.dof}) for {self.name}'s joints, got {q.shape}")
            return self._serial.numpy(q)
        with torch.no_grad():
            T = self._fk_base(torch.as_tensor(q, dtype=self.dtype, device=self.device))[self._link_frames]
        return T.transpose(0, 1).double().cpu().numpy()

    def transform_points(self, q: torch.Tensor, poses: torch.Tensor | None = None) -> torch.Tensor:
        """q (B, n) -> (B, M, 3) robot points in the base frame, T_q(P); differentiable in q.
        `poses`: `link_poses(q)`, when the caller has them already."""
        poses = self.link_poses(q) if poses is None else poses
        if len(poses) <= 8:  # a few configurations: one gather of each point's pose is cheapest
            T = poses[:, self.point_collision_links]  # (B, M, 4, 4)
            return torch.einsum("bmij,mj->bmi", T[..., :3, :3], self.points) + T[..., :3, 3]
        T = poses.transpose(0, 1)  # (L, B, 4, 4): each link's contiguous run of points in one product
        return torch.cat([torch.einsum("bij,mj->bmi", T[li, :, :3, :3], self.points[run]) + T[li, :, None, :3, 3]
                          for li, run in self._point_runs], dim=1)

    def extra_repr(self) -> str:
        return f"name={self.name}, dof={self.dof}, links={len(self.link_names)}, points={len(self.points)}"


def _exact_chain_constants(chain: pk.Chain, urdf: URDFModel) -> dict[str, torch.Tensor]:
    """float64 joint-origin transforms and axes for the chain's frames, from our own URDF parse.

    pytorch-kinematics parses origins in float32 (a ~1e-8 m error at the Panda's fingers); FK in
    float64 should be exact to the file. The pk values are checked against ours to pin the frame order.
    """
    statics = chain._static_offsets.detach().to(torch.float64).clone()
    axes = chain.axes.detach().to(torch.float64).clone()
    names = chain.get_joint_parameter_names()
    for idx, frame_name in chain.idx_to_frame.items():
        joint = urdf.parent_joint(frame_name)
        if joint is None:
            continue
        exact = torch.from_numpy(joint.origin)
        if not torch.allclose(exact, statics[idx], atol=1e-5):
            raise RuntimeError(f"pytorch-kinematics frame {frame_name!r} does not match joint {joint.name!r} of {urdf.path}")
        statics[idx] = exact
        if joint.name in names:
            axes[names.index(joint.name)] = torch.from_numpy(joint.axis / np.linalg.norm(joint.axis))
    return {"static_offsets": statics, "axes": axes}
