"""Fuzzing the import readers: seeded random damage to small valid `.npz`, HDF5 and LeRobot sources.

Each damaged source goes through the real command (`samp.data.__main__.main(["import", ...])`) in one worker
process whose address space is limited (RLIMIT_AS) to WORKER_MEMORY: a declared size believed before reading
shows up there as a MemoryError. The oracle per source: it imports and `verify` passes, or the command exits
2 with exactly one line on stderr (file descriptor 2, so C libraries printing there are caught too) and no
traceback. The damage: byte flips (more of them in the headers and the parquet footer, where the declared
shapes and sizes live), truncations, and header edits (an .npy header's shape, dtype and order rewritten; a
LeRobot info.json's features replaced)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile

import numpy as np

SEED = 52
PER_FORMAT = 50  # mutations of each of the three formats: 150 imports, about 30 s on one core
WORKER_MEMORY = 3 << 30  # the worker's address space: the interpreter with torch and pybullet take about 0.9 GiB
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
AWAY = np.array([0.6, -0.5, 0.2, -2.0, 0.1, 1.8, 0.5])
NAMES = [f"panda_joint{i}" for i in range(1, 8)]
SCENE = {"obstacles": [{"kind": "box", "name": "table", "size": [1.2, 1.6, 0.04],
                        "pose": {"position": [0.5, 0, -0.02]}}]}

# Runs every import of the manifest in one process (one interpreter start for all), the command's stderr
# (fd 2) captured per import; prints one JSON line per import.
WORKER = r"""
import contextlib, io, json, os, resource, sys, tempfile, traceback
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from samp.data.__main__ import main

def run(argv):
    out, rc, trace = io.StringIO(), None, ""
    with tempfile.TemporaryFile() as err:
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            with contextlib.redirect_stdout(out):
                rc = main(argv)
        except SystemExit as exit:
            rc = exit.code
        except BaseException:
            trace = traceback.format_exc()
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        return rc, err.read().decode(errors="replace"), trace

for case in json.load(open(sys.argv[1])):
    rc, err, trace = run(["import", *case["args"]])
    verified = run(["verify", case["name"], "root=" + case["root"]])[0] if rc == 0 else None
    print(json.dumps({"case": case["what"], "rc": rc, "stderr": err, "trace": trace, "verified": verified}), flush=True)
print(json.dumps({"maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}), flush=True)
"""


def _trajectories() -> np.ndarray:
    """(2, 20, 7): two straight joint-space motions, which pass the expert's checks in the table scene."""
    return np.stack([np.linspace(HOME, AWAY, 20), np.linspace(AWAY, HOME, 20)])


def _npz_bytes(scene: str) -> bytes:
    q = _trajectories()
    out = io.BytesIO()
    np.savez(out, joint_positions=q.reshape(40, 7), episode_ends=np.array([20, 40]),
             timestamps=np.tile(np.arange(20) / 10.0, 2), joint_names=np.array(NAMES), scene=np.array([scene]))
    return out.getvalue()


def _hdf5_bytes(tmp_path, scene: str) -> bytes:
    import h5py

    path = tmp_path / "valid.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("joint_positions", data=_trajectories(), chunks=(1, 10, 7), compression="gzip")
        f["timestamps"] = np.tile(np.arange(20) / 10.0, (2, 1))
        f["joint_names"] = NAMES
        f["scene"] = scene
    return path.read_bytes()


def _parquet_bytes() -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    q = _trajectories()
    out = io.BytesIO()
    pq.write_table(pa.table({"observation.state": [r.tolist() for r in q.reshape(40, 7)],
                             "episode_index": [0] * 20 + [1] * 20, "frame_index": list(range(20)) * 2,
                             "timestamp": [i / 10 for i in range(20)] * 2}), out)
    return out.getvalue()


INFO = {"codebase_version": "v2.1", "fps": 10,
        "features": {"observation.state": {"dtype": "float32", "shape": [7], "names": NAMES}}}
INFO_EDITS = [{"features": []}, {"features": {"observation.state": 7}}, [],
              {"features": {"observation.state": {"names": {"motors": NAMES[:3]}}}},
              {"features": {"observation.state": {"names": [1, 2, 3, 4, 5, 6, 7]}}},
              {"features": {"observation.state": {"names": NAMES[::-1]}}},
              {"features": {"observation.state": {"names": [NAMES[0]] * 7}}}]


def _flip(data: bytes, rng, hot: int) -> bytes:
    """1 to 4 bytes xor-ed, half of them within the `hot` first (or last, if negative) bytes."""
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        near = rng.random() < 0.5 and hot
        i = int(rng.integers(0, abs(hot))) if near else int(rng.integers(0, len(out)))
        out[i if not near or hot > 0 else len(out) - 1 - i] ^= int(rng.integers(1, 256))
    return bytes(out)


def _rezip(data: bytes, rng, change) -> bytes:
    """The npz rebuilt (valid CRCs, stored or deflated) with one member's bytes passed through `change`."""
    src = zipfile.ZipFile(io.BytesIO(data))
    members = src.namelist()
    target = members[int(rng.integers(len(members)))]
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED if rng.random() < 0.5 else zipfile.ZIP_DEFLATED) as dst:
        for name in members:
            dst.writestr(name, change(src.read(name)) if name == target else src.read(name))
    return out.getvalue()


def _npy_edit(raw: bytes, rng) -> bytes:
    """One .npy member with its header rewritten: its shape, dtype or order."""
    from numpy.lib import format as npy

    edits = [("shape", (10**9, 7)), ("shape", (2**62, 2**62)), ("shape", (41, 7)), ("shape", (40, 8)),
             ("shape", (8, 5, 7)), ("shape", ()), ("shape", (-1, 7)), ("descr", "|O"), ("descr", "<U7"),
             ("descr", ">f8"), ("descr", "<c16"), ("descr", "|V8"), ("descr", "<f2"), ("descr", "<i8"),
             ("fortran_order", True)]
    field, value = edits[int(rng.integers(len(edits)))]
    fp = io.BytesIO(raw)
    npy.read_magic(fp)  # np.savez writes version 1.0 for these
    shape, fortran, dtype = npy.read_array_header_1_0(fp)
    body = io.BytesIO()
    npy.write_array_header_1_0(body, {"shape": shape, "fortran_order": fortran, "descr": npy.dtype_to_descr(dtype),
                                      field: value})
    return body.getvalue() + raw[fp.tell():]


def _parquet_edit(rng) -> bytes:
    """A data file whose columns have another type or layout than LeRobot writes."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = [r.tolist() for r in _trajectories().reshape(40, 7)]
    ep, frame, stamp = [0] * 20 + [1] * 20, list(range(20)) * 2, [i / 10 for i in range(20)] * 2
    edits = [{"observation.state": [r[0] for r in rows]}, {"observation.state": [r[:6] for r in rows[:3]] + rows[3:]},
             {"observation.state": [None] + rows[1:]}, {"observation.state": [[None] + r[1:] for r in rows]},
             {"observation.state": [[str(v) for v in r] for r in rows]},
             {"observation.state": pa.array(rows, pa.list_(pa.float32(), 7))},
             {"observation.state": pa.array(rows, pa.large_list(pa.float64()))},
             {"episode_index": pa.array([2**64 - 1] * 20 + [0] * 20, pa.uint64())},
             {"episode_index": [str(e) for e in ep]}, {"episode_index": [None] + ep[1:]},
             {"frame_index": [float(f) for f in frame]}, {"timestamp": [float("nan")] * 40},
             {"timestamp": [str(t) for t in stamp]}, {"frame_index": [0] * 40}]
    columns = {"observation.state": rows, "episode_index": ep, "frame_index": frame, "timestamp": stamp,
               **edits[int(rng.integers(len(edits)))]}
    out = io.BytesIO()
    pq.write_table(pa.table(columns), out, row_group_size=int(rng.integers(5, 41)))
    return out.getvalue()


def _mutations(tmp_path, scene: str) -> list[dict]:
    """PER_FORMAT damaged copies of each valid source, written under tmp_path -> the worker's cases."""
    rng = np.random.default_rng(SEED)
    root = tmp_path / "datasets"
    valid = {"npz": _npz_bytes(scene), "h5": _hdf5_bytes(tmp_path, scene), "parquet": _parquet_bytes()}
    cases = []
    for fmt in ("npz", "h5", "lerobot"):
        for k in range(PER_FORMAT):
            name = f"{fmt}{k}"
            how = ["flip", "truncate", "edit"][int(rng.integers(3))]
            if fmt == "lerobot":
                folder = tmp_path / name
                (folder / "meta").mkdir(parents=True)
                (folder / "data" / "chunk-000").mkdir(parents=True)
                info, parquet = json.dumps(INFO).encode(), valid["parquet"]
                if how == "edit" and rng.random() < 0.5:
                    info = json.dumps(INFO_EDITS[int(rng.integers(len(INFO_EDITS)))]).encode()
                elif how == "edit":
                    parquet = _parquet_edit(rng)
                elif rng.random() < 0.3:
                    info = _flip(info, rng, 0) if how == "flip" else info[:int(rng.integers(len(info)))]
                else:
                    parquet = _flip(parquet, rng, -600 if rng.random() < 0.5 else len(parquet)) if how == "flip" \
                        else parquet[:int(rng.integers(len(parquet)))]
                (folder / "meta" / "info.json").write_bytes(info)
                (folder / "data" / "chunk-000" / "episode_000000.parquet").write_bytes(parquet)
                source, extra = folder, [f"scene={scene}"]
            else:
                data = valid[fmt]
                if how == "flip" and fmt == "npz":  # inside one member (its CRC made right again), else the zip's own
                    data = _rezip(data, rng, lambda raw: _flip(raw, rng, 128)) if rng.random() < 0.7 else \
                        _flip(data, rng, 0)
                elif how == "flip":
                    data = _flip(data, rng, 2048)
                elif how == "truncate":
                    data = data[:int(rng.integers(len(data)))]
                elif fmt == "npz":
                    data = _rezip(data, rng, lambda raw: _npy_edit(raw, rng))
                else:  # an HDF5 header edit: an 8-byte field of the metadata set to all ones or zeros
                    data = bytearray(data)
                    at = int(rng.integers(0, 2048 // 8)) * 8
                    data[at:at + 8] = b"\xff" * 8 if rng.random() < 0.5 else bytes(8)
                    data = bytes(data)
                source, extra = tmp_path / f"{name}.{fmt}", []
                source.write_bytes(data)
            cases.append({"what": f"{name} ({how})", "name": name, "root": str(root),
                          "args": [f"source={source}", f"name={name}", "resolutions=8", "eval_problems=0",
                                   f"root={root}", *extra]})
    return cases


def test_damaged_sources_import_or_give_one_line(tmp_path):
    scene = tmp_path / "table.json"
    scene.write_text(json.dumps(SCENE))
    cases = _mutations(tmp_path, str(scene))
    manifest = tmp_path / "cases.json"
    manifest.write_text(json.dumps(cases))
    out = subprocess.run([sys.executable, "-c", WORKER, str(manifest), str(WORKER_MEMORY)], capture_output=True,
                         text=True, timeout=240, env={**os.environ, "OMP_NUM_THREADS": "1"})
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
    assert out.returncode == 0 and lines and "maxrss_kb" in lines[-1], out.stderr[-3000:]
    results, maxrss = lines[:-1], lines[-1]["maxrss_kb"]
    assert len(results) == len(cases)
    bad = []
    for r in results:
        err = r["stderr"].strip().splitlines()
        if r["trace"]:
            bad.append(f"{r['case']}: traceback\n{r['trace'][-1500:]}")
        elif r["rc"] == 0 and r["verified"] != 0:
            bad.append(f"{r['case']}: imported, but verify exited {r['verified']}")
        elif r["rc"] not in (0, 2) or (r["rc"] == 2 and (len(err) != 1 or not err[0].startswith("error: "))):
            bad.append(f"{r['case']}: exit {r['rc']}, stderr {r['stderr'][-600:]!r}")
    assert not bad, f"{len(bad)} of {len(results)} damaged sources misbehaved:\n" + "\n".join(bad)
    outcomes = sorted({r["rc"] for r in results})
    assert outcomes == [0, 2], f"the damage should leave some sources importable and refuse others, got {outcomes}"
    assert maxrss * 1024 < WORKER_MEMORY, f"the worker's peak resident memory {maxrss} kB"
