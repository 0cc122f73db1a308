"""The whole-robot query of a trained hash-grid SDF against trimesh and against itself (per-link min,
culling), its gradients, its bad-input errors and its artifacts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.robot_sdf.samples import link_signed_distance

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


def _link_points(panda, name: str, count: int, seed: int) -> np.ndarray:
    """Uniform points in the link's (unpadded) bounding box, slightly enlarged."""
    lo, hi = panda.geometry[name].mesh.bounds
    pad = 0.01
    return np.random.default_rng(seed).uniform(lo - pad, hi + pad, size=(count, 3))


def _local(trained_sdf, name: str, points: np.ndarray) -> np.ndarray:
    i = trained_sdf.link_names.index(name)
    with torch.no_grad():
        d = trained_sdf.local_distance(torch.as_tensor(points, dtype=torch.float32), torch.full((len(points),), i))
    return d.double().numpy()


def test_sign_is_right_inside_and_outside_each_link(panda, trained_sdf):
    """Points more than 5 mm from a link's surface get the right sign. The fixture trains on 9k samples
    per link for seconds, so a handful of points in the sparsely sampled box corners may still be wrong:
    at most 0.5 % per link (measured: 3 of about 30k over all links)."""
    margin = 0.005  # metres; the fixture's surface error is below 1 mm median, 4 mm at the 99th percentile
    for k, name in enumerate(panda.link_names):
        p = _link_points(panda, name, 4000, seed=k)
        truth = link_signed_distance(panda.geometry[name], p)
        pred = _local(trained_sdf, name, p)
        inside, outside = truth < -margin, truth > margin
        assert inside.sum() > 50 and outside.sum() > 50, f"{name}: too few test points"
        wrong_in, wrong_out = (pred[inside] >= 0).sum(), (pred[outside] <= 0).sum()
        assert wrong_in + wrong_out <= 0.005 * (inside.sum() + outside.sum()), (
            f"{name}: {wrong_in}/{inside.sum()} inside points predicted outside, "
            f"{wrong_out}/{outside.sum()} outside points predicted inside (expected at most 0.5 %)")


def test_zero_level_set_lies_on_the_mesh_surface(panda, trained_sdf):
    for k, name in enumerate(panda.link_names):
        surface = panda.geometry[name].mesh.sample(2000, seed=100 + k)
        d = np.abs(_local(trained_sdf, name, surface))
        assert np.median(d) < 0.001 and np.quantile(d, 0.99) < 0.004, (
            f"{name}: |sdf| on the surface has median {np.median(d) * 1e3:.2f} mm, 99% {np.quantile(d, 0.99) * 1e3:.2f} mm; "
            "expected < 1 mm and < 4 mm")


def _mixed_points(panda, q: torch.Tensor, per_config: int = 600, seed: int = 0) -> torch.Tensor:
    """(B, N, 3): robot points, points anywhere in the workspace and far outside it."""
    g = torch.Generator().manual_seed(seed)
    robot_points = panda.transform_points(q)[:, ::4]
    workspace = torch.rand(len(q), per_config, 3, generator=g) * torch.tensor([2.0, 2.0, 1.4]) - torch.tensor([1.0, 1.0, 0.1])
    far = torch.randn(len(q), 20, 3, generator=g) * 3
    return torch.cat([robot_points, workspace, far], dim=1)


def _random_q(panda, batch: int, seed: int = 0) -> torch.Tensor:
    lo, hi = panda.joint_limits.T.float()
    return lo + (hi - lo) * torch.rand(batch, panda.dof, generator=torch.Generator().manual_seed(seed))


def test_whole_robot_query_is_the_min_over_links_and_culling_changes_nothing(panda, trained_sdf):
    q = _random_q(panda, 6)
    points = _mixed_points(panda, q)
    with torch.no_grad():
        per_link = trained_sdf.link_distances(points, q)  # (B, N, L), every pair evaluated
        full = trained_sdf.query(points, q, cull=False)
        culled = trained_sdf.query(points, q)
    assert per_link.shape == (*points.shape[:2], len(panda.link_names))
    torch.testing.assert_close(full, per_link.min(dim=-1).values, atol=0, rtol=0)
    diff = (culled - full).abs().max().item()
    assert diff <= 1e-6, f"culling changed a distance by {diff} m"
    # Each per-link value is the link's own distance of the point moved into that link's frame by FK.
    fk = panda.fk(q)
    for i, name in enumerate(panda.link_names[::3]):
        li = panda.link_names.index(name)
        T = fk[name]
        local = torch.einsum("bji,bnj->bni", T[:, :3, :3], points - T[:, None, :3, 3])
        with torch.no_grad():
            own = trained_sdf.local_distance(local.reshape(-1, 3), torch.full((local.shape[0] * local.shape[1],), li))
        torch.testing.assert_close(per_link[..., li].reshape(-1), own, atol=2e-6, rtol=0)


def test_whole_robot_query_matches_trimesh(panda, trained_sdf):
    from samp.robot_sdf.evaluate import SDFEvalConfig, _link_poses, heldout_robot_set

    centres, scales = trained_sdf.centres.double().numpy(), trained_sdf.scales.double().numpy()
    data = heldout_robot_set(panda, centres, scales, SDFEvalConfig(configs=2, robot_points=1000))
    for q, points, truth in zip(data["q"], data["points"], data["sdf"]):
        with torch.no_grad():
            pred = trained_sdf.query(torch.as_tensor(points[None], dtype=torch.float32),
                                     torch.as_tensor(q[None], dtype=torch.float32))[0].double().numpy()
        near = np.abs(truth) < 0.05
        mae = np.abs(pred - truth)[near].mean()
        assert mae < 0.002, f"whole-robot MAE near the surface {mae * 1e3:.2f} mm against trimesh"
    assert _link_poses(panda, data["q"]).shape == (2, len(panda.link_names), 4, 4)


def test_gradients_with_respect_to_points(panda, trained_sdf):
    """The autograd gradient of the (culled) query equals central differences of the query itself
    (float64 copy; a few points on kinks of the min or the box residual may differ)."""
    import copy

    from samp.robot import load_robot
    from samp.robot_sdf.whole_robot import RobotSDF

    sdf64 = RobotSDF(load_robot("panda", dtype=torch.float64), copy.deepcopy(trained_sdf.net).double(),
                     trained_sdf.centres, trained_sdf.scales)
    q = _random_q(panda, 2, seed=3).double()
    points = _mixed_points(panda, q.float(), per_config=50, seed=3).double()[:, ::5].clone().requires_grad_(True)
    grad = torch.autograd.grad(sdf64.query(points, q).sum(), points)[0]
    assert torch.isfinite(grad).all()
    h = 1e-6
    for axis in range(3):
        step = torch.zeros(3, dtype=torch.float64)
        step[axis] = h
        with torch.no_grad():
            fd = (sdf64.query(points + step, q) - sdf64.query(points - step, q)) / (2 * h)
        close = (grad[..., axis] - fd).abs() < 1e-3 * (1 + fd.abs())
        assert close.float().mean() > 0.97, f"axis {axis}: autograd and finite differences disagree at {(~close).sum()} points"


def test_bad_input_is_refused_with_a_clear_message(panda, trained_sdf):
    q = panda.home[None].float()
    points = torch.zeros(1, 5, 3)
    with pytest.raises(ValueError, match=r"points must have shape \(B, N, 3\).*use points\[None\]"):
        trained_sdf.query(torch.zeros(5, 3), q)
    with pytest.raises(ValueError, match=r"points must have shape \(B, N, 3\)"):
        trained_sdf.query(torch.zeros(1, 5, 2), q)
    with pytest.raises(ValueError, match=r"q must have shape \(B, 7\)"):
        trained_sdf.query(points, torch.zeros(1, 6))
    with pytest.raises(ValueError, match="same batch size"):
        trained_sdf.query(torch.zeros(2, 5, 3), q)
    with pytest.raises(TypeError, match="dtype"):
        trained_sdf.query(points.double(), q)


def test_artifact_round_trip_and_robot_checks(panda, trained_sdf, tmp_path):
    from samp.robot import load_robot
    from samp.robot_sdf import load_robot_sdf, save_artifact
    from samp.robot_sdf.artifact import net_spec

    spec = net_spec(trained_sdf.net)
    path = save_artifact(tmp_path / "robot_sdf.pt", trained_sdf, spec, "abc123")
    for ref in (path, tmp_path):  # the file, and the folder holding it
        loaded = load_robot_sdf(ref, panda)
        q = _random_q(panda, 2, seed=9)
        points = _mixed_points(panda, q, per_config=100)
        with torch.no_grad():
            torch.testing.assert_close(loaded.query(points, q), trained_sdf.query(points, q), atol=0, rtol=0)
    assert loaded.meta["dataset_id"] == "abc123"
    with pytest.raises(ValueError, match="trained for robot 'panda'.*not 'iiwa'"):
        load_robot_sdf(path, "iiwa")
    with pytest.raises(ValueError, match="trained for robot 'panda'.*'iiwa'.*Retrain"):
        load_robot_sdf(path, load_robot("iiwa"))
    other = load_robot("panda")
    other.asset_hash = "0" * 64  # the same name, other meshes
    with pytest.raises(ValueError, match="URDF or meshes differ"):
        load_robot_sdf(path, other)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_robot_sdf(tmp_path / "missing_run")
    (tmp_path / "empty_run").mkdir()
    with pytest.raises(FileNotFoundError, match="no robot_sdf.pt"):
        load_robot_sdf(tmp_path / "empty_run")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a robot SDF"):
        load_robot_sdf(tmp_path / "junk.pt")
