"""The inserted object's mesh, posed in the camera frame: geometry both the pipeline
(which poses it from the bundle's ``meta.json``) and the renderers (its shadow and the
sky it hides) use, so it lives below both."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class PosedMesh:
    """Triangles of the object in the camera frame: vertices (N, 3), faces (M, 3);
    ``source`` the mesh file they came from (None: made from maps) and
    ``source_to_camera`` (4, 4) the matrix placing the file's coordinates in the camera
    frame, the depth alignment included as one scale about the camera at the mesh's
    centre (a renderer that reads the file's materials imports it with it)."""

    vertices: np.ndarray
    faces: np.ndarray
    source: str | None = None
    source_to_camera: np.ndarray | None = None


def load_posed_mesh(meta: dict, alignment: dict | None = None) -> PosedMesh | None:
    """The bundle's mesh posed in the camera frame, or None when the bundle has none.

    ``alignment`` (``{"a", "b"}``, the job's depth alignment ``z' = a z + b``) moves each
    vertex along its viewing ray like the object's depth map."""
    path = meta.get("mesh")
    M = meta.get("object_to_camera")
    if not path or M is None or not Path(path).is_file():
        return None
    V0, F = _object_frame_mesh(Path(path))
    if V0 is None:
        return None
    M = np.asarray(M, np.float64)
    V = V0 @ M[:3, :3].T + M[:3, 3]
    to_camera = M.copy()
    if alignment:
        a, b = float(alignment.get("a", 1.0)), float(alignment.get("b", 0.0))
        z = -V[:, 2]
        scale = np.where(z > 1e-9, (a * z + b) / np.maximum(z, 1e-9), 1.0)
        zc = float(np.mean(z))
        to_camera = np.diag([*([(a * zc + b) / zc if zc > 1e-9 else 1.0] * 3), 1.0]) @ M
        V = V * scale[:, None]
    return PosedMesh(V, F, str(path), to_camera)


# The meshes read, in their own frame, by the file's (path, size, mtime): every job of an
# object poses the same vertices (a 48 MB OBJ was parsed again for each of 1000 jobs).
# The last few kept: memory flat in the number of objects.
_READ: dict = {}
KEEP_MESHES = 2


def _object_frame_mesh(path: Path):
    """(vertices (V, 3) float64, faces (F, 3) int64) of every mesh in the file, in its
    own frame, or (None, None) when it holds no faces; read once per content."""
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    hit = _READ.get(key)
    if hit is None:
        import trimesh

        scene = trimesh.load(str(path), force="scene")
        vs, fs, off = [], [], 0
        for m in scene.dump(concatenate=False):
            if not hasattr(m, "faces") or len(m.faces) == 0:
                continue
            vs.append(np.asarray(m.vertices, np.float64))
            fs.append(np.asarray(m.faces, np.int64) + off)
            off += len(m.vertices)
        hit = (np.concatenate(vs), np.concatenate(fs)) if vs else (None, None)
        for a in hit:
            if a is not None:
                a.setflags(write=False)  # shared by every job of the object
        _READ[key] = hit
        while len(_READ) > KEEP_MESHES:
            _READ.pop(next(iter(_READ)))
    else:
        _READ[key] = _READ.pop(key)  # most recently used last
    return hit


__all__ = ["PosedMesh", "load_posed_mesh"]
