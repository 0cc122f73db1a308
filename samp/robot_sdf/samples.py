"""Training samples of the robot SDF: per link, points in the link's normalised box with exact signed
distances, stored as a versioned dataset (docs/design.md section 5).

Each link's box is a cube around its collision mesh: centre c = the centre of the mesh's bounding box,
half side s = largest half extent + `padding` metres. A link-frame point p maps to u = (p - c) / s in
[-1, 1]^3, and a distance d in metres to d / s ("normalised units"); `scale` undoes it. The padding puts
every point within `padding` of the mesh inside the box, so the near band is learnt, not extrapolated.

Per link: `near` points are surface samples (area-weighted) moved by isotropic Gaussian offsets, an
equal share per scale in `near_sigmas` (metres); `uniform` points are uniform in the box. Points that
leave the box are redrawn. The target is the exact signed distance in metres from trimesh (negative
inside), on the link's welded convex parts (`samp.robot.geometry`): the minimum over parts, which for
the one-part links of the Panda and iiwa is trimesh's value on the link mesh itself.

Storage: one `.npz` per link (`links/<link>.npz`: near_points, near_sdf, uniform_points, uniform_sdf,
float32, normalised units) and `normalisation.json`. Plain numpy arrays, not MCAP: these are dense
tables read once into memory, with no time axis or schema that Foxglove would add value to; MCAP is
the format for trajectories and scenes. Generation is seeded per link (the same config gives the same
bytes) and resumable: finished links wait in `<root>/<name>/.partial-<config hash>/` until all are done.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from samp.scene.sdf import mesh_signed_distance

__all__ = ["SAMPLES_FORMAT", "SampleConfig", "SampleSet", "dataset_name", "ensure_samples", "link_normalisation",
           "link_signed_distance", "load_samples"]

SAMPLES_FORMAT = "robot-sdf-samples-v1"  # bump when the sampling algorithm changes
NORMALISATION_FILE = "normalisation.json"
LINKS_DIR = "links"


@dataclass
class SampleConfig:
    """How many samples per link and where (conf/robot_sdf_samples/default.yaml)."""

    near_per_link: int = 100_000
    uniform_per_link: int = 50_000
    near_sigmas: list[float] = field(default_factory=lambda: [0.001, 0.003, 0.01, 0.03])  # metres
    padding: float = 0.05  # metres between the mesh's bounding box and the link box
    seed: int = 0

    def __post_init__(self):
        if self.near_per_link < 0 or self.uniform_per_link < 0 or self.near_per_link + self.uniform_per_link == 0:
            raise ValueError(f"sample counts must be non-negative and not both zero, got near={self.near_per_link}, "
                             f"uniform={self.uniform_per_link}")
        if not self.near_sigmas or min(self.near_sigmas) <= 0:
            raise ValueError(f"near_sigmas must be positive metres, got {self.near_sigmas}")
        if self.padding < 0:
            raise ValueError(f"padding must be >= 0 metres, got {self.padding}")


def dataset_name(robot_name: str) -> str:
    return f"robot_sdf_samples_{robot_name}"


def link_normalisation(robot, padding: float) -> tuple[np.ndarray, np.ndarray]:
    """(L, 3) box centres and (L,) half sides [m] of every collision link, in `robot.link_names` order."""
    centres, scales = [], []
    for name in robot.link_names:
        lo, hi = robot.geometry[name].mesh.bounds
        centres.append((lo + hi) / 2)
        scales.append((hi - lo).max() / 2 + padding)
    return np.asarray(centres, dtype=np.float64), np.asarray(scales, dtype=np.float64)


def link_signed_distance(geometry, points: np.ndarray) -> np.ndarray:
    """(N, 3) link-frame points -> (N,) exact signed distance [m] to the link (negative inside): the
    minimum over its convex parts of trimesh's signed distance (chunked; trimesh is positive inside)."""
    out = np.full(len(points), np.inf)
    for part in geometry.parts:
        out = np.minimum(out, -mesh_signed_distance(part, points))
    return out


def _draw_in_box(rng: np.random.Generator, count: int, draw, centre: np.ndarray, scale: float) -> np.ndarray:
    """`count` points from `draw(rng, n) -> (n, 3)` that lie in the box, redrawing the ones outside."""
    kept, have = [], 0
    while have < count:
        p = draw(rng, max(2 * (count - have), 1024))
        p = p[np.abs(p - centre).max(axis=1) <= scale]
        kept.append(p)
        have += len(p)
    return np.concatenate(kept)[:count] if kept else np.zeros((0, 3))


def _link_samples(geometry, centre: np.ndarray, scale: float, cfg: SampleConfig, seed) -> dict[str, np.ndarray]:
    import trimesh

    rng = np.random.default_rng(seed)
    mesh = geometry.mesh
    sigmas = np.asarray(cfg.near_sigmas)

    def near(r, n):
        surface, _ = trimesh.sample.sample_surface(mesh, n, seed=r)
        return surface + r.normal(size=(n, 3)) * sigmas[r.integers(len(sigmas), size=n)][:, None]

    def uniform(r, n):
        return centre + r.uniform(-scale, scale, size=(n, 3))

    out = {}
    for kind, draw, count in (("near", near, cfg.near_per_link), ("uniform", uniform, cfg.uniform_per_link)):
        p = _draw_in_box(rng, count, draw, centre, scale)
        d = link_signed_distance(geometry, p) if len(p) else np.zeros(0)
        out[f"{kind}_points"] = ((p - centre) / scale).astype(np.float32)
        out[f"{kind}_sdf"] = (d / scale).astype(np.float32)
    return out


def _config_hash(robot, cfg: SampleConfig) -> str:
    key = {"format": SAMPLES_FORMAT, "robot": robot.name, "asset_hash": robot.asset_hash,
           "links": list(robot.link_names), "config": asdict(cfg)}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def ensure_samples(robot, cfg: SampleConfig | dict, root: Path | None = None, progress: bool = True) -> Path:
    """The dataset folder of `robot`'s SDF samples for `cfg`: an existing one with the same config hash
    (robot asset hash, links, sampling settings, seed), else a freshly generated one."""
    from samp.data.registry import datasets_root, finalize_dataset, list_datasets
    from samp.provenance import code_version

    cfg = cfg if isinstance(cfg, SampleConfig) else SampleConfig(**cfg)
    root = Path(root) if root is not None else datasets_root()
    name, chash = dataset_name(robot.name), _config_hash(robot, cfg)
    existing = [d for d in list_datasets(root) if d["name"] == name and d.get("config_hash") == chash]
    if existing:
        return Path(max(existing, key=lambda d: d["created"])["path"])

    centres, scales = link_normalisation(robot, cfg.padding)
    partial = root / name / f".partial-{chash}"
    (partial / LINKS_DIR).mkdir(parents=True, exist_ok=True)
    seeds = np.random.SeedSequence(cfg.seed).spawn(len(robot.link_names))
    for i, link in enumerate(robot.link_names):
        path = partial / LINKS_DIR / f"{link}.npz"
        if path.is_file():  # finished by an earlier, interrupted call
            continue
        if progress:
            print(f"  robot SDF samples {robot.name}: link {i + 1}/{len(robot.link_names)} {link}", flush=True)
        arrays = _link_samples(robot.geometry[link], centres[i], float(scales[i]), cfg, seeds[i])
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **arrays)
        tmp.replace(path)
    (partial / NORMALISATION_FILE).write_text(json.dumps(
        {"links": list(robot.link_names), "centres": centres.tolist(), "scales": scales.tolist()}, indent=2))

    manifest = {"robot": robot.name, "robot_asset_hash": robot.asset_hash, "generator": SAMPLES_FORMAT,
                "config": asdict(cfg), "config_hash": chash, "seed": cfg.seed, "code_version": code_version(),
                "counts": {"links": len(robot.link_names), "near_per_link": cfg.near_per_link,
                           "uniform_per_link": cfg.uniform_per_link}}
    staging = root / name / f".finalize-{chash}"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(partial, staging)  # finalize renames its input; the partial stays until that succeeded
    folder = finalize_dataset(staging, name, manifest, root)
    shutil.rmtree(partial, ignore_errors=True)
    return folder


@dataclass
class SampleSet:
    """Loaded samples of all links as flat tensors (normalised units).

    points (P, 3), sdf (P,), link (P,) index into `link_names`, near (P,) bool; centres (L, 3) and
    scales (L,) map the links' boxes back to metres.
    """

    robot: str
    robot_asset_hash: str
    dataset_id: str
    link_names: list[str]
    centres: torch.Tensor
    scales: torch.Tensor
    points: torch.Tensor
    sdf: torch.Tensor
    link: torch.Tensor
    near: torch.Tensor

    def link_slice(self, index: int) -> slice:
        """The contiguous rows of link `index` (points are stored link by link)."""
        rows = torch.nonzero(self.link == index).flatten()
        return slice(int(rows[0]), int(rows[-1]) + 1) if len(rows) else slice(0, 0)


def load_samples(folder: Path | str) -> SampleSet:
    """Read a samples dataset folder into one `SampleSet`, after checking it as `python -m samp.data verify`
    does (the manifest's own hash, every file's sha256)."""
    from samp.data.registry import DatasetError, file_problems, read_manifest, recreate_hint

    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest.get("generator") != SAMPLES_FORMAT:
        raise ValueError(f"{folder} is not a robot SDF sample set ({SAMPLES_FORMAT}); its generator is "
                         f"{manifest.get('generator')!r}")
    problems = file_problems(folder, manifest)
    if problems:
        raise DatasetError(f"sample set {folder} fails verification: {'; '.join(problems[:3])}; "
                           f"{recreate_hint(folder, manifest, 'let the next robot SDF training sample it again')}")
    norm = json.loads((folder / NORMALISATION_FILE).read_text())
    points, sdf, link, near = [], [], [], []
    for i, name in enumerate(norm["links"]):
        with np.load(folder / LINKS_DIR / f"{name}.npz") as z:
            for kind in ("near", "uniform"):
                p = z[f"{kind}_points"]
                points.append(p)
                sdf.append(z[f"{kind}_sdf"])
                link.append(np.full(len(p), i, dtype=np.int64))
                near.append(np.full(len(p), kind == "near"))
    return SampleSet(robot=manifest["robot"], robot_asset_hash=manifest["robot_asset_hash"], dataset_id=manifest["id"],
                     link_names=list(norm["links"]), centres=torch.tensor(norm["centres"], dtype=torch.float64),
                     scales=torch.tensor(norm["scales"], dtype=torch.float64),
                     points=torch.from_numpy(np.concatenate(points)), sdf=torch.from_numpy(np.concatenate(sdf)),
                     link=torch.from_numpy(np.concatenate(link)), near=torch.from_numpy(np.concatenate(near)))
