"""Reading a mesh file that a user's URDF or scene names: bounded and checked before trimesh builds it.

Every collision, visual and obstacle mesh goes through `load_mesh`, so a file that claims more than it
holds is refused with its path and the reason, not with whatever trimesh raises deep inside its parser
(a binary STL whose header claims 4e9 triangles used to end in "No points given").
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["MAX_MESH_BYTES", "STL_HEADER_BYTES", "STL_TRIANGLE_BYTES", "load_mesh", "check_mesh_file"]

# Largest mesh file read (64 MiB). Collision meshes are a few MB at most; trimesh holds several times a
# file's size while it parses, so this keeps one bad file from taking the machine's memory.
MAX_MESH_BYTES = 64 * 2**20
# Binary STL layout: an 80-byte header and a uint32 triangle count, then 50 bytes per triangle
# (normal and three vertices as 12 float32, and a uint16 attribute).
STL_HEADER_BYTES = 84
STL_TRIANGLE_BYTES = 50

# What trimesh's parsers raise on a malformed file (seen in the fuzz tests); anything else stays a bug.
_PARSE_ERRORS = (ValueError, IndexError, KeyError, TypeError, AttributeError, struct.error, EOFError,
                 UnicodeDecodeError, zipfile.BadZipFile, OverflowError)


def _check_stl(path: Path, size: int) -> None:
    """Refuse a binary STL whose declared triangle count does not match its length. A file starting with
    `solid` may be ASCII; trimesh reads it as binary only when the count matches exactly, as here."""
    with open(path, "rb") as f:
        head = f.read(STL_HEADER_BYTES)
    if head.lstrip().startswith(b"solid"):
        return
    if len(head) < STL_HEADER_BYTES:
        raise ValueError(f"mesh {path} is not an STL: {size} bytes, shorter than the {STL_HEADER_BYTES}-byte "
                         "header of a binary STL and not an ASCII one (no 'solid'); export the mesh again")
    count = int.from_bytes(head[80:84], "little")
    expected = STL_HEADER_BYTES + STL_TRIANGLE_BYTES * count
    if expected != size:
        raise ValueError(f"mesh {path} is a damaged binary STL: its header declares {count} triangles "
                         f"({expected} bytes), but the file has {size} bytes; export the mesh again")


def check_mesh_file(path: Path) -> int:
    """The size in bytes of the mesh file at `path`, after refusing a missing file, one over
    `MAX_MESH_BYTES` and a binary STL that declares more (or fewer) triangles than it holds."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh {path} does not exist")
    size = path.stat().st_size
    if size > MAX_MESH_BYTES:
        raise ValueError(f"mesh {path} has {size} bytes, over samp's limit of {MAX_MESH_BYTES} "
                         "(samp.meshes.MAX_MESH_BYTES); simplify it (a collision mesh needs few triangles)")
    if path.suffix.lower() == ".stl":
        _check_stl(path, size)
    return size


def load_mesh(path: Path, solid: bool = False, process: bool = False, **kwargs):
    """The mesh file at `path` as one `trimesh.Trimesh` (all its bodies together), checked first
    (`check_mesh_file`); ValueError naming the file when trimesh cannot read it, or when it has no
    triangles or non-finite vertices, or, with `solid`, when its vertices span no volume (a convex hull,
    which samp makes of collision meshes, needs four points off one plane). `process` and `kwargs` go to
    `trimesh.load`."""
    import trimesh

    check_mesh_file(path)
    try:
        mesh = trimesh.load(path, force="mesh", process=process, **kwargs)
    except _PARSE_ERRORS as err:
        first = (str(err).splitlines() or [""])[0]
        raise ValueError(f"mesh {path} cannot be read ({type(err).__name__}: {first}); "
                         "check that the file is a mesh in the format its extension says") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError(f"mesh {path} has no triangles; export the mesh again or remove it from the file that "
                         "names it")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"mesh {path} has vertices that are not finite numbers (NaN or infinity); "
                         "export the mesh again")
    if solid and _flat(mesh.vertices):
        raise ValueError(f"mesh {path} is flat: its {len(mesh.vertices)} vertices lie on one plane or line, so it "
                         "has no inside and no convex hull; use a closed mesh (or a box) for collisions")
    return mesh


def _flat(vertices: np.ndarray) -> bool:
    """(V, 3) -> whether the points span less than three dimensions (to 1e-9 of their extent)."""
    if len(vertices) < 4:
        return True
    s = np.linalg.svd(vertices - vertices.mean(axis=0), compute_uv=False)
    return bool(s[2] <= 1e-9 * s[0])
