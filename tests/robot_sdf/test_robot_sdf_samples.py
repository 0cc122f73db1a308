"""SDF sample sets: exact distances from trimesh, the manifest, determinism and reuse by config hash."""

from __future__ import annotations

import json

import numpy as np
import pytest

from samp.robot_sdf.samples import SampleConfig, dataset_name, ensure_samples, link_signed_distance, load_samples


def test_samples_are_exact_signed_distances_in_normalised_units(panda, panda_samples):
    folder, s = panda_samples
    for i, name in enumerate(panda.link_names):
        rows = np.flatnonzero(s.link.numpy() == i)[::97]
        u = s.points[rows].double().numpy()
        assert np.abs(u).max() <= 1 + 1e-6, f"{name}: a sample lies outside its box"
        metres = u * s.scales[i].item() + s.centres[i].numpy()
        truth = link_signed_distance(panda.geometry[name], metres)
        np.testing.assert_allclose(s.sdf[rows].double().numpy() * s.scales[i].item(), truth, atol=1e-6)
        mesh = panda.geometry[name].mesh
        inside = mesh.contains(metres)
        assert ((truth < 0) == inside)[np.abs(truth) > 1e-5].all(), f"{name}: sign disagrees with mesh.contains"


def test_near_and_uniform_counts_and_box_padding(panda, panda_samples):
    _, s = panda_samples
    counts = np.bincount(s.link.numpy(), minlength=len(panda.link_names))
    assert (counts == 9000).all(), counts
    assert int(s.near.sum()) == 6000 * len(panda.link_names)
    for i, name in enumerate(panda.link_names):
        lo, hi = panda.geometry[name].mesh.bounds
        np.testing.assert_allclose(s.centres[i].numpy(), (lo + hi) / 2, atol=1e-12)
        assert abs(s.scales[i].item() - ((hi - lo).max() / 2 + 0.05)) < 1e-12


def test_manifest_records_provenance_and_the_dataset_verifies(panda, panda_samples):
    from samp.data.registry import read_manifest, verify_dataset

    folder, s = panda_samples
    m = read_manifest(folder)
    assert m["name"] == dataset_name("panda") == "robot_sdf_samples_panda"
    assert m["robot"] == "panda" and m["robot_asset_hash"] == panda.asset_hash
    assert m["config"]["near_per_link"] == 6000 and m["seed"] == 0 and len(m["config_hash"]) == 16
    assert set(m["code_version"]) == {"package", "git_commit", "git_dirty"}
    assert len(m["files"]) == len(panda.link_names) + 1  # one .npz per link + normalisation.json
    assert verify_dataset(folder) == []
    assert s.dataset_id == m["id"] == folder.name


def test_same_config_is_reused_and_generation_is_deterministic(panda, panda_samples, tmp_path, monkeypatch):
    import samp.robot_sdf.samples as samples_module

    folder, _ = panda_samples
    root = folder.parent.parent
    calls = []
    monkeypatch.setattr(samples_module, "_link_samples", lambda *a, **k: calls.append(a) or {})
    assert ensure_samples(panda, SampleConfig(near_per_link=6000, uniform_per_link=3000), root) == folder
    assert calls == [], "an existing dataset with the same config hash was regenerated"
    monkeypatch.undo()
    cfg = SampleConfig(near_per_link=300, uniform_per_link=100, seed=5)
    a = ensure_samples(panda, cfg, tmp_path / "a", progress=False)
    b = ensure_samples(panda, cfg, tmp_path / "b", progress=False)
    assert a.name == b.name, "the same config and seed gave different content ids"
    c = ensure_samples(panda, SampleConfig(near_per_link=300, uniform_per_link=100, seed=6), tmp_path / "a", progress=False)
    assert c != a and c.parent == a.parent
    assert not any(p.name.startswith(".partial") for p in a.parent.iterdir())


def test_interrupted_generation_resumes_from_finished_links(panda, tmp_path, monkeypatch):
    import samp.robot_sdf.samples as samples_module

    real, done = samples_module._link_samples, []

    def flaky(*args, **kwargs):
        if len(done) == 3:
            raise KeyboardInterrupt
        done.append(1)
        return real(*args, **kwargs)

    cfg = SampleConfig(near_per_link=200, uniform_per_link=100)
    monkeypatch.setattr(samples_module, "_link_samples", flaky)
    with pytest.raises(KeyboardInterrupt):
        ensure_samples(panda, cfg, tmp_path, progress=False)
    monkeypatch.setattr(samples_module, "_link_samples", lambda *a, **k: done.append(2) or real(*a, **k))
    folder = ensure_samples(panda, cfg, tmp_path, progress=False)
    assert done.count(2) == len(panda.link_names) - 3, "finished links were sampled again"
    reference = ensure_samples(panda, cfg, tmp_path / "fresh", progress=False)
    assert folder.name == reference.name


def test_bad_sample_config_and_foreign_folder(tmp_path):
    with pytest.raises(ValueError, match="near_sigmas"):
        SampleConfig(near_sigmas=[0.0])
    with pytest.raises(ValueError, match="sample counts"):
        SampleConfig(near_per_link=0, uniform_per_link=0)
    (tmp_path / "manifest.json").write_text(json.dumps({"format_version": 1, "files": {}, "generator": "other"}))
    with pytest.raises(ValueError, match="not a robot SDF sample set"):
        load_samples(tmp_path)
