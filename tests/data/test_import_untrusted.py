"""`samp.data import` of hostile sources (issue 52): each is refused by the real command with exit 2 and one
line on stderr naming the file and the key, before anything is read that the file only points at or only
declares, and nothing is published.

The sources are written here, small, with the same libraries that write real ones (numpy, h5py, pyarrow);
the two that declare tens of gigabytes run the command in a process whose address space is limited, so a
size believed before reading fails the test with a MemoryError rather than taking the machine's memory."""

from __future__ import annotations

import fcntl
import io
import json
import os
import pty
import resource
import struct
import subprocess
import sys
import termios
import zipfile

import numpy as np
import pytest

HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
AWAY = np.array([0.6, -0.5, 0.2, -2.0, 0.1, 1.8, 0.5])
Q = np.stack([np.linspace(HOME, AWAY, 20), np.linspace(AWAY, HOME, 20)])  # (2, 20, 7): both pass every check
NAMES = [f"panda_joint{i}" for i in range(1, 8)]
TABLE = {"obstacles": [{"kind": "box", "name": "table", "size": [1.2, 1.6, 0.04],
                        "pose": {"position": [0.5, 0, -0.02]}}]}
LIMIT = 3 << 30  # the address space of a command run under _limited: the interpreter itself takes about 0.9 GiB


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "table.json"
    path.write_text(json.dumps(TABLE))
    return str(path)


def _args(tmp_path, source, *extra) -> list[str]:
    return ["import", f"source={source}", "name=bad", "resolutions=8", "eval_problems=0", "progress=false",
            f"root={tmp_path / 'datasets'}", *extra]


def _refused(capsys, tmp_path, source, *extra) -> str:
    """Run the command in this process: it must exit 2 with one stderr line and publish nothing -> the line."""
    from samp.data.__main__ import main

    rc = main(_args(tmp_path, source, *extra))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: "), (rc, err)
    assert not list((tmp_path / "datasets").rglob("manifest.json")), "a refused import must publish nothing"
    return err[0]


def _limited(tmp_path, source, *extra) -> subprocess.CompletedProcess:
    """The command in a process of its own, its address space limited to LIMIT."""
    def preexec():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))
    return subprocess.run([sys.executable, "-m", "samp.data", *_args(tmp_path, source, *extra)], capture_output=True,
                          text=True, timeout=120, preexec_fn=preexec, env={**os.environ, "OMP_NUM_THREADS": "1"})


def _h5(path, fill):
    import h5py

    with h5py.File(path, "w") as f:
        fill(f)
    return path


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def _lerobot(folder, info=None, state=None, episodes=None):
    """A LeRobot folder of one parquet file holding Q's two episodes (or the `state`/`episodes` given)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    (folder / "meta").mkdir(parents=True)
    (folder / "data" / "chunk-000").mkdir(parents=True)
    info = {"features": {"observation.state": {"dtype": "float32", "shape": [7], "names": NAMES}}} \
        if info is None else info
    (folder / "meta" / "info.json").write_text(info if isinstance(info, str) else json.dumps(info))
    state = [r.tolist() for r in Q.reshape(40, 7)] if state is None else state
    pq.write_table(pa.table({"observation.state": state,
                             "episode_index": pa.array([0] * 20 + [1] * 20) if episodes is None else episodes,
                             "frame_index": list(range(20)) * 2, "timestamp": [i / 10 for i in range(20)] * 2}),
                   folder / "data" / "chunk-000" / "episode_000000.parquet")
    return folder


# --------------------------------------------------------------------------------- a file that reads another
def _indirection(kind, tmp_path, scene):
    import h5py

    other = _h5(tmp_path / "other.h5", lambda f: f.create_dataset("q", data=Q))
    secret = tmp_path / "secret.bin"
    secret.write_bytes(np.full(Q.shape, 0.1).tobytes())

    def fill(f):
        f["scene"] = scene
        if kind == "external storage":
            f.create_dataset("joint_positions", shape=Q.shape, dtype="f8", external=[(str(secret), 0, Q.nbytes)])
        elif kind == "virtual":
            layout = h5py.VirtualLayout(shape=Q.shape, dtype="f8")
            layout[:] = h5py.VirtualSource(str(other), "q", shape=Q.shape)
            f.create_virtual_dataset("joint_positions", layout)
        elif kind == "soft link":
            f["q"] = Q
            f["joint_positions"] = h5py.SoftLink("/q")
        elif kind == "external link":
            f["joint_positions"] = h5py.ExternalLink(str(other), "/q")
        else:  # a group where the array belongs
            f.create_group("joint_positions").create_dataset("q", data=Q)
    return _h5(tmp_path / "demos.h5", fill)


@pytest.mark.parametrize("kind, said", [
    ("external storage", "is stored in external files ['{tmp}/secret.bin']; an import reads only data stored in "
                         "the file itself"),
    ("virtual", "is a virtual dataset (its data lives in other files)"),
    ("soft link", "is a link to '/q'; an import reads only datasets stored in the file itself"),
    ("external link", "is a link to '{tmp}/other.h5:/q'"),
    ("group", "is an HDF5 group, expected a dataset (an array)")])
def test_hdf5_indirections_are_refused_before_reading(kind, said, tmp_path, scene, capsys):
    """The fault: external storage imported the bytes of another local file (refused only by chance, as
    outside the joint limits), the virtual and linked datasets imported another file's data, and a group
    gave an AttributeError."""
    source = _indirection(kind, tmp_path, scene)
    line = _refused(capsys, tmp_path, source)
    assert line.startswith(f"error: {source}: `joint_positions` {said.format(tmp=tmp_path)}"), line


# ------------------------------------------------------------------------------ LeRobot links out of the folder
@pytest.mark.parametrize("what", ["a data file", "a data folder", "meta/info.json", "a dangling link"])
def test_lerobot_links_out_of_the_folder_are_refused(what, tmp_path, scene, capsys):
    """The fault: every one was followed (the file and the folder imported, hashed into the manifest's
    parents and published), and a dangling link gave a FileNotFoundError traceback."""
    outside = _lerobot(tmp_path / "elsewhere")
    folder = _lerobot(tmp_path / "lerobot")
    link, target = {
        "a data file": ("data/chunk-000/episode_000001.parquet", outside / "data/chunk-000/episode_000000.parquet"),
        "a data folder": ("data/chunk-001", outside / "data/chunk-000"),
        "meta/info.json": ("meta/info.json", outside / "meta/info.json"),
        "a dangling link": ("data/chunk-000/episode_000002.parquet", tmp_path / "gone.parquet")}[what]
    (folder / link).unlink(missing_ok=True)
    os.symlink(target, folder / link)
    line = _refused(capsys, tmp_path, folder, f"scene={scene}")
    said = "a symbolic link that leads nowhere" if what == "a dangling link" else \
        f"a symbolic link to {target}, outside the dataset folder"
    assert line == f"error: {folder}: {folder / link} is {said}; " + (
        "remove it" if what == "a dangling link" else "an import reads only the folder's own files: copy the file in"
    ), line


# ----------------------------------------------------------------------------- declared sizes, in bytes, first
def _npy(array=None, header=None, data=b"") -> bytes:
    """An .npy member: the header of `array` (or the `header` dict given) and its data (or `data`)."""
    from numpy.lib import format as npy

    out = io.BytesIO()
    if array is not None:
        np.save(out, array)
        return out.getvalue()
    npy.write_array_header_1_0(out, header)
    return out.getvalue() + data


def _zip(path, **members):
    with zipfile.ZipFile(path, "w") as z:
        for key, raw in members.items():
            z.writestr(f"{key}.npy", raw)
    return path


@pytest.mark.parametrize("fmt", ["npz", "h5"])
def test_declared_sizes_are_bounded_in_bytes_before_allocation(fmt, tmp_path, scene):
    """The fault: a 6 KB HDF5 file declaring (1e7, 7) took 2.4 GB (here a MemoryError), an npz whose header
    declares (1e9, 7) allocated 52 GiB before reading anything."""
    if fmt == "npz":
        source = _zip(tmp_path / "bomb.npz", scene=_npy(np.array([scene])),
                      joint_positions=_npy(header={"descr": "<f8", "fortran_order": False, "shape": (10**9, 7)},
                                           data=bytes(64)))
        said = "declares shape (1000000000, 7) of float64, 56000000000 bytes"
    else:
        source = _h5(tmp_path / "huge.h5", lambda f: (
            f.create_dataset("joint_positions", shape=(10**7, 7), dtype="f8", chunks=(1000, 7)),
            f.create_dataset("episode_ends", data=[10**7]), f.__setitem__("scene", scene)))
        assert source.stat().st_size < 10_000
        said = "declares shape (10000000, 7) of float64, 560000000 bytes"
    out = _limited(tmp_path, source)
    assert out.returncode == 2 and out.stderr.strip() == (
        f"error: {source}: `joint_positions` {said}, more than the 536870912 an import reads per array "
        "(MAX_ARRAY_BYTES); split it into several files"), out.stderr[-2000:]


def test_an_npy_header_is_checked_against_its_member(tmp_path, scene, capsys):
    """The fault: a member declaring more rows than it holds was read up to its end, then refused as
    'EOF: reading array data' (no file, no key); a garbled header text gave a TokenError traceback."""
    q = _npy(Q)
    longer = q.replace(b"(2, 20, 7)", b"(2, 21, 7)")
    source = _zip(tmp_path / "long.npz", joint_positions=longer, scene=_npy(np.array([scene])))
    assert _refused(capsys, tmp_path, source) == (
        f"error: {source}: `joint_positions` declares shape (2, 21, 7) of float64 (2352 bytes), but its member holds "
        "2240 bytes of data; the file is damaged or was cut short")
    garbled = q.replace(b"'shape': (2,", b"'shape': ((2,")
    source = _zip(tmp_path / "garbled.npz", joint_positions=garbled, scene=_npy(np.array([scene])))
    assert _refused(capsys, tmp_path, source).startswith(
        f"error: {source}: member `joint_positions.npy` is not a readable .npy array: ")


# ------------------------------------------------------------------------- shapes and dtypes, per field
def _fields(case, tmp_path, scene):
    """(source, extra arguments, the expected line after `error: PATH`) for one malformed field; only the
    case's own source is written."""
    import pyarrow as pa

    s, flat = np.array([scene]), Q.reshape(40, 7)
    stem = "".join(c if c.isalnum() else "_" for c in case)
    npz = lambda **arrays: _npz(tmp_path / f"{stem}.npz", **arrays)  # noqa: E731
    h5 = lambda *items: _h5(tmp_path / f"{stem}.h5", lambda f: [f.__setitem__(k, v) for k, v in items])  # noqa: E731
    lerobot = lambda **kw: (_lerobot(tmp_path / stem, **kw), [f"scene={scene}"])  # noqa: E731
    parquet = "/data/chunk-000/episode_000000.parquet: column"
    names = f": `joint_names` names 7 joints {NAMES}, but the joint positions have 6 columns"
    build, said = {
        "names vs columns": (lambda: npz(joint_positions=Q[..., :6], joint_names=np.array(NAMES), scene=s), names),
        "names vs columns (h5)": (lambda: h5(("joint_positions", Q[..., :6]), ("joint_names", NAMES),
                                             ("scene", scene)), names),
        "text positions": (lambda: npz(joint_positions=np.full((20, 7), "x"), episode_ends=np.array([20]), scene=s),
                           ": `joint_positions` holds <U1 (text), expected numbers"),
        "text positions (h5)": (lambda: h5(("joint_positions", np.full((20, 7), b"x")), ("episode_ends", [20]),
                                           ("scene", scene)), ": `joint_positions` holds |S1 (text), expected numbers"),
        "no scene in scene": (lambda: npz(joint_positions=Q, scene=np.array([], dtype="U5")),
                              ": `scene` must hold one scene reference, holds 0"),
        "timestamps shape": (lambda: npz(joint_positions=flat, episode_ends=np.array([20, 40]),
                                         timestamps=np.zeros((3, 20)), scene=s),
                             ": `timestamps` has shape (3, 20), expected (40,): one per row of joint_positions"),
        "float ends": (lambda: npz(joint_positions=flat, episode_ends=np.array([20.0, 1e300]), scene=s),
                       ": `episode_ends` holds float64 (floats), expected integers"),
        "wrapping ends": (lambda: npz(joint_positions=flat, episode_ends=np.array([2**64 - 20, 40], dtype=np.uint64),
                                      scene=s), ": `episode_ends` must hold end rows in 1..40 (the row count of "
                                                "joint_positions), got [18446744073709551596, 40]"),
        "2-D ends": (lambda: npz(joint_positions=flat, episode_ends=np.array([[20, 40]]), scene=s),
                     ": `episode_ends` has shape (1, 2), expected ndim 1"),
        "float scene index": (lambda: npz(joint_positions=Q, scenes=s, episode_scene=np.array([0.5, 7.0])),
                              ": `episode_scene` holds float64 (floats), expected integers"),
        "nan timestamps": (lambda: npz(joint_positions=Q, timestamps=np.full((2, 20), np.nan), scene=s),
                           None),  # refused per trajectory, as a NaN position is
        "scalar feature": (lambda: lerobot(state=[float(i) for i in range(40)]),
                           f"{parquet} 'observation.state' is one number per frame (a scalar feature); expected a "
                           "list of joint positions per frame"),
        "text feature": (lambda: lerobot(state=[["a"] * 7] * 40),
                         f"{parquet} 'observation.state' holds lists of string, expected lists of numbers"),
        "ragged feature": (lambda: lerobot(state=[[0.0] * 7] * 39 + [[0.0] * 3]),
                           f"{parquet} 'observation.state' must hold the same number of values in every frame, holds "
                           "3 to 7"),
        "names vs state": (lambda: lerobot(info={"features": {"observation.state": {"names": NAMES[:5]}}}),
                           f" (feature 'observation.state'): meta/info.json's `names` of 'observation.state' names 5 "
                           f"joints {NAMES[:5]}, but the joint positions have 7 columns"),
        "info a list": (lambda: lerobot(info="[1, 2]"),
                        "/meta/info.json: expected an object with a `features` object, got list"),
        "names a number": (lambda: lerobot(info={"features": {"observation.state": {"names": 7}}}),
                           "/meta/info.json: `features.observation.state.names` must be a list of joint names, got 7"),
        "deep info": (lambda: lerobot(info="[" * 100_000 + "]" * 100_000),
                      "/meta/info.json is not readable JSON: maximum recursion depth exceeded"),
        "info not JSON": (lambda: lerobot(info="{not json"),
                          "/meta/info.json is not readable JSON: Expecting property name enclosed in double quotes"),
        "huge episode index": (lambda: lerobot(episodes=pa.array([2**64 - 1] * 20 + [0] * 20, pa.uint64())),
                               f"{parquet} 'episode_index' holds 18446744073709551615, beyond the int64 range of an "
                               "index"),
    }[case]
    source = build()
    return (source, []) if not isinstance(source, tuple) else source, said


@pytest.mark.parametrize("case", ["names vs columns", "names vs columns (h5)", "text positions", "text positions (h5)",
                                  "no scene in scene", "timestamps shape", "float ends", "wrapping ends", "2-D ends",
                                  "float scene index", "nan timestamps", "scalar feature", "text feature",
                                  "ragged feature", "names vs state", "info a list", "names a number", "deep info",
                                  "info not JSON", "huge episode index"])
def test_each_field_is_checked_naming_file_and_key(case, tmp_path, scene, capsys):
    """The faults: IndexError, AttributeError, TypeError and RecursionError tracebacks; numpy's messages
    naming neither file nor key; a NaN timestamp, a wrapped uint64 and an episode index beyond int64 taken."""
    (source, extra), said = _fields(case, tmp_path, scene)
    line = _refused(capsys, tmp_path, source, *extra)
    if said is None:
        assert line.startswith("error: every one of the 2 trajectories was refused; first: ") and \
            line.endswith(": timestamp 0 is not finite (NaN or inf)"), line
    else:
        assert line.startswith(f"error: {source}{said}"), line


def test_absurd_positions_give_one_short_line(tmp_path, scene):
    """The fault: two steps 1e308 apart printed numpy's overflow warning (three stderr lines in all) and a
    300-digit jump."""
    q = Q.copy()
    q[:, 5:] = 1e308
    q[:, 10:] = -1e308
    source = _npz(tmp_path / "absurd.npz", joint_positions=q, scene=np.array([scene]))
    out = _limited(tmp_path, source)
    assert out.returncode == 2 and out.stderr.strip() == (
        "error: every one of the 2 trajectories was refused; first: absurd.npz#0 (scene "
        f"{scene}): jump of 1e+308 rad in panda_joint1 between steps 4 and 5 (more than max_jump=0.5)"), out.stderr


# ---------------------------------------------------------------------------------------- progress bars
def test_the_progress_bar_is_drawn_only_on_a_terminal(tmp_path, scene):
    """The fault: stderr redirected to a log got the bar's carriage-return frames."""
    source = _npz(tmp_path / "demos.npz", joint_positions=Q, scene=np.array([scene]))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "samp.data", "import", f"source={source}", "resolutions=8", "eval_problems=0",
               f"root={tmp_path / 'datasets'}"]
    logged = subprocess.run([*command, "name=logged"], capture_output=True, text=True, timeout=120, env=env)
    assert logged.returncode == 0, logged.stderr
    assert "\r" not in logged.stderr and "traj" not in logged.stderr, repr(logged.stderr)
    assert "imported 2 of 2 trajectories (0 refused)" in logged.stdout, logged.stdout
    parent, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # tqdm draws nothing 0 columns wide
    try:
        shown = subprocess.run([*command, "name=shown"], stdout=subprocess.PIPE, stderr=child, timeout=120, env=env)
        os.close(child)
        child = None
        terminal = b""
        while True:
            try:
                chunk = os.read(parent, 65536)
            except OSError:  # the terminal's other end is closed: all of it has been read
                break
            if not chunk:
                break
            terminal += chunk
    finally:
        os.close(parent)
        if child is not None:
            os.close(child)
    assert shown.returncode == 0 and b"\r" in terminal and b"import shown" in terminal, terminal[-500:]
