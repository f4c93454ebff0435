"""Mesh files on the Python side: format, content hash, bounding box, placement checks.

Meshes are in metres with +Y up (glTF's convention; OBJ, PLY and STL are read with their
coordinates as stored, taken as Y-up too). The bounding box is computed here with trimesh
on the mesh as loaded, and Blender is told to keep the same raw coordinates (see
``zcomp_cli/blender/scripts/render_intrinsics.py``), so ``Pose.object_to_camera(bbox)`` places the
rendered mesh exactly.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.errors import GeometryError, InputError

# file suffix -> the format name the Blender script imports
MESH_FORMATS = {".obj": "obj", ".glb": "gltf", ".gltf": "gltf", ".ply": "ply", ".stl": "stl"}


@dataclass(frozen=True)
class MeshInfo:
    """What the parent needs to know about a mesh file."""

    path: Path
    format: str
    content_hash: str
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    vertices: np.ndarray  # (N, 3) float64, mesh coordinates (for frustum checks)


def mesh_format(path) -> str:
    """Format name for a mesh path from its suffix; InputError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix not in MESH_FORMATS:
        raise InputError(
            f"unknown mesh format {suffix or '(no suffix)'!r}; supported: "
            + ", ".join(sorted(MESH_FORMATS)),
            where=str(path),
        )
    return MESH_FORMATS[suffix]


def side_files(path) -> list[Path]:
    """Files a mesh references next to itself (OBJ's MTL and its textures, a .gltf's
    buffers and images): they are part of the content and of the hash."""
    path = Path(path)
    found: list[Path] = []
    try:
        if path.suffix.lower() == ".obj":
            text = path.read_text(errors="replace")
            for m in re.finditer(r"^\s*mtllib\s+(.+?)\s*$", text, re.M):
                mtl = path.parent / m.group(1)
                if mtl.is_file():
                    found.append(mtl)
                    mtext = mtl.read_text(errors="replace")
                    for t in re.finditer(r"^\s*(?:map_\w+|bump|disp|norm)\s+(?:-\S+\s+\S+\s+)*(\S.*?)\s*$", mtext, re.M):
                        tex = mtl.parent / t.group(1)
                        if tex.is_file():
                            found.append(tex)
        elif path.suffix.lower() == ".gltf":
            import json

            doc = json.loads(path.read_text())
            for entry in doc.get("buffers", []) + doc.get("images", []):
                uri = entry.get("uri", "")
                if uri and not uri.startswith("data:") and (path.parent / uri).is_file():
                    found.append(path.parent / uri)
    except (OSError, ValueError):
        pass  # a malformed side file is the loader's problem, not the hash's
    return sorted(set(found))


def content_hash(path) -> str:
    """sha256 of the mesh file's bytes and of the side files it references (each side
    file with its name, which the mesh refers to; the mesh's own name does not count)."""
    path = Path(path)
    h = hashlib.sha256()
    for p in [path] + side_files(path):
        if p != path:
            h.update(b"\0" + p.name.encode() + b"\0")
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def load_mesh_info(path) -> MeshInfo:
    """Check, hash and measure a mesh file.

    Raises:
        InputError: missing file, unknown format, unreadable or empty mesh.
        GeometryError: non-finite or zero-size geometry.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("mesh file not found", where=str(path))
    if not path.is_file():
        raise InputError("mesh path is not a file", where=str(path))
    fmt = mesh_format(path)
    import trimesh

    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(f"cannot read mesh: {type(exc).__name__}: {exc}", where=str(path)) from exc
    meshes = [g for g in scene.dump(concatenate=False)] if hasattr(scene, "dump") else []
    verts = [np.asarray(m.vertices, dtype=np.float64) for m in meshes
             if hasattr(m, "faces") and len(getattr(m, "faces", [])) > 0]
    if not verts:
        raise InputError("mesh has no faces (empty, a point cloud or unreadable)", where=str(path))
    vertices = np.concatenate(verts, axis=0)
    if not np.all(np.isfinite(vertices)):
        raise GeometryError("mesh has non-finite vertex coordinates", where=str(path))
    bmin, bmax = vertices.min(axis=0), vertices.max(axis=0)
    if float(np.max(bmax - bmin)) <= 1e-9:
        raise GeometryError("mesh has zero size", where=str(path))
    return MeshInfo(path=path.resolve(), format=fmt, content_hash=content_hash(path),
                    bbox_min=bmin, bbox_max=bmax, vertices=vertices)


def check_in_view(points_cam, camera, *, near: float = 1e-3) -> None:
    """Raise GeometryError when transformed mesh points cannot appear in the image:
    all behind the camera (z >= -near), or all outside one side of the view frustum.

    Args:
        points_cam: (N, 3) camera-frame points (OpenGL: in front means z < 0).
        camera: a ``zcomp_cli.camera.Camera``.
    """
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[:, 2]
    if np.all(z >= -near):
        raise GeometryError(
            f"object is behind the camera (all points have z >= {-near:g}; "
            "objects in front of the camera need z < 0)")
    d = -z  # positive in front
    # Frustum planes in pixel terms: u = fx x / d + cx must fall in [0, W] etc. Written
    # as linear inequalities in (x, y, d) so points behind the camera need no division.
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    u_num = fx * p[:, 0] + cx * d  # u * d
    v_num = -fy * p[:, 1] + cy * d  # v * d
    outside = [
        np.all(d <= near),
        np.all(u_num <= 0),
        np.all(u_num >= camera.width * d),
        np.all(v_num <= 0),
        np.all(v_num >= camera.height * d),
    ]
    if any(outside):
        raise GeometryError("object lies entirely outside the camera's field of view")
