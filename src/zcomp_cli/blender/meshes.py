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
    # (N, 3) float64, mesh coordinates: at most MAX_EXTENT_POINTS points whose convex
    # hull holds the mesh (``extent_points``), for every frustum test, pixel box and
    # radius taken per pose (1000 poses of a 48 MB OBJ spent 66 s transforming all its
    # vertices)
    vertices: np.ndarray


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


# Side-file names read from a mesh file, by the file's (path, size, mtime): a batch of
# 1000 jobs on one 48 MB OBJ read it once per job to find its MTL (10 minutes of
# planning). A few entries: memory flat in the number of objects.
_MTLLIBS: dict = {}
KEEP_PARSED = 8


def _stat_key(path: Path):
    st = path.stat()
    return (str(path.resolve()), st.st_size, st.st_mtime_ns)


def _obj_mtllibs(path: Path) -> list[str]:
    """The ``mtllib`` names an OBJ file gives, read once per content (``_stat_key``)."""
    key = _stat_key(path)
    hit = _MTLLIBS.get(key)
    if hit is None:
        names = []
        with open(path, "rb") as f:
            for line in f:  # line by line: the file may be large, only these lines matter
                t = line.lstrip()
                if t.startswith(b"mtllib"):
                    m = re.match(r"^mtllib\s+(.+?)\s*$", t.decode("utf-8", "replace"))
                    if m:
                        names.append(m.group(1))
        hit = _MTLLIBS[key] = names
        while len(_MTLLIBS) > KEEP_PARSED:
            _MTLLIBS.pop(next(iter(_MTLLIBS)))
    return list(hit)


def _references(path: Path) -> list[Path]:
    """Every existing path a mesh file references next to itself (OBJ's MTL and its
    textures, a .gltf's buffers and images), whatever its type (a FIFO included: the
    caller decides), never read unless it is a regular file."""
    found: list[Path] = []
    try:
        if path.suffix.lower() == ".obj":
            for name in _obj_mtllibs(path):
                mtl = path.parent / name
                if not mtl.exists():
                    continue
                found.append(mtl)
                if not mtl.is_file():
                    continue
                mtext = mtl.read_text(errors="replace")
                for t in re.finditer(r"^\s*(?:map_\w+|bump|disp|norm)\s+(?:-\S+\s+\S+\s+)*(\S.*?)\s*$", mtext, re.M):
                    tex = mtl.parent / t.group(1)
                    if tex.exists():
                        found.append(tex)
        elif path.suffix.lower() == ".gltf":
            import json

            doc = json.loads(path.read_text())
            entries = []
            if isinstance(doc, dict):
                for k in ("buffers", "images"):
                    if isinstance(doc.get(k), list):
                        entries += [e for e in doc[k] if isinstance(e, dict)]
            for entry in entries:
                uri = entry.get("uri", "")
                if isinstance(uri, str) and uri and not uri.startswith("data:") and (path.parent / uri).exists():
                    found.append(path.parent / uri)
    except (OSError, ValueError):
        pass  # a malformed side file is the loader's problem, not the hash's
    return sorted(set(found))


def side_files(path) -> list[Path]:
    """Files a mesh references next to itself (OBJ's MTL and its textures, a .gltf's
    buffers and images): they are part of the content and of the hash."""
    return [p for p in _references(Path(path)) if p.is_file()]


# glTF/GLB image types whose size a header tells (the others are not checked)
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp", ".tga", ".webp"}


def _embedded_images(path: Path) -> list[tuple[str, bytes]]:
    """(name, first bytes) of the images a GLB embeds (its JSON chunk's ``images``
    with a ``bufferView`` into the binary chunk). Reads the JSON chunk and, per image,
    the first 64 KiB of its bytes only."""
    import json
    import struct

    out: list[tuple[str, bytes]] = []
    with open(path, "rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] != b"glTF":
            return out
        n, kind = struct.unpack("<II", f.read(8))
        if kind != 0x4E4F534A or n > 64 << 20:  # "JSON"; a header past 64 MiB is not one we read
            return out
        doc = json.loads(f.read(n))
        bin_at = 12 + 8 + n + 8  # the BIN chunk's data
        if not isinstance(doc, dict):
            return out
        views = doc.get("bufferViews") if isinstance(doc.get("bufferViews"), list) else []
        for k, img in enumerate(doc.get("images") or []):
            if not isinstance(img, dict) or not isinstance(img.get("bufferView"), int):
                continue
            v = img["bufferView"]
            view = views[v] if 0 <= v < len(views) and isinstance(views[v], dict) else {}
            off = view.get("byteOffset", 0)
            if not isinstance(off, int):
                continue
            f.seek(bin_at + off)
            out.append((str(img.get("name") or f"images[{k}]"), f.read(1 << 16)))
    return out


def image_size_from_bytes(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a PNG or JPEG from its first bytes, else None."""
    import struct

    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        return struct.unpack(">II", data[16:24])
    if data[:2] == b"\xff\xd8":
        i = 2
        while i + 9 < len(data):
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
                i += 2
                continue
            size = struct.unpack(">H", data[i + 2:i + 4])[0]
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # a start of frame
                h, w = struct.unpack(">HH", data[i + 5:i + 9])
                return w, h
            i += 2 + size
    return None


_SUSPECT = re.compile(rb"(?i)nan|inf|e\+?[0-9]{3}")
_VERTEX = re.compile(rb"^[ \t]*v[ \t]+([^\n#]*)", re.M)


def _obj_nonfinite_vertex(path: Path) -> int | None:
    """1-based index of the first vertex of an OBJ with a non-finite coordinate (a
    loader drops it silently and renders a cut or shifted mesh), else None."""
    data = path.read_bytes()
    if not _SUSPECT.search(data):
        return None
    for k, m in enumerate(_VERTEX.finditer(data), start=1):
        for tok in m.group(1).split()[:3]:
            try:
                v = float(tok)
            except ValueError:
                continue  # the loader's problem
            if v != v or v in (float("inf"), float("-inf")):
                return k
    return None


def mesh_file_problems(path) -> list[str]:
    """Cheap checks of a mesh file and what it references, for validation (before
    anything renders): side files that are not regular files (a FIFO would hang the
    loader), textures over the pixel budget (read from their headers, embedded GLB
    images included), non-finite OBJ vertices. Messages name the offending file."""
    from zcomp_cli.imageio import image_header
    from zcomp_cli.limits import pixel_budget_problem

    path = Path(path)
    problems: list[str] = []
    refs = _references(path)
    for p in refs:
        if not p.is_file():
            problems.append(f"{p.name} (referenced by {path.name}) is not a regular file")
    textures: list[tuple[str, tuple[int, int] | None]] = []
    for p in refs:
        if p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES:
            try:
                textures.append((p.name, image_header(p)[:2]))
            except ValueError:
                textures.append((p.name, None))  # unreadable: Blender says so, per job
    if path.suffix.lower() == ".glb":
        try:
            textures += [(name, image_size_from_bytes(data)) for name, data in _embedded_images(path)]
        except (OSError, ValueError, TypeError):
            pass  # a malformed GLB: the loader's problem
    for name, size in textures:
        budget = size and pixel_budget_problem(*size)
        if budget:
            problems.append(f"texture {name} of {path.name} is {budget}")
    if path.suffix.lower() == ".obj":
        k = _obj_nonfinite_vertex(path)
        if k is not None:
            problems.append(f"{path.name}: vertex {k} has a non-finite coordinate (nan or inf)")
    return problems


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
        # process=False: trimesh's processing drops non-finite vertices silently (and
        # Blender then renders a cut or shifted mesh); materials are not needed here
        scene = trimesh.load(str(path), force="scene", process=False, skip_materials=True)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(f"cannot read mesh: {type(exc).__name__}: {exc}", where=str(path)) from exc
    meshes = [g for g in scene.dump(concatenate=False)] if hasattr(scene, "dump") else []
    meshes = [m for m in meshes if hasattr(m, "faces") and len(getattr(m, "faces", [])) > 0]
    if not meshes:
        raise InputError("mesh has no faces (empty, a point cloud or unreadable)", where=str(path))
    if not all(np.all(np.isfinite(np.asarray(m.vertices, dtype=np.float64))) for m in meshes):
        raise GeometryError("mesh has non-finite vertex coordinates (nan or inf)", where=str(path))
    # the vertices faces use (what Blender draws; unreferenced ones would stretch the box)
    try:
        vertices = np.concatenate([np.asarray(m.vertices, dtype=np.float64)[np.unique(np.asarray(m.faces))]
                                   for m in meshes], axis=0)
    except IndexError:
        raise InputError("mesh has faces naming vertices it does not have", where=str(path)) from None
    bmin, bmax = vertices.min(axis=0), vertices.max(axis=0)
    if float(np.max(bmax - bmin)) <= 1e-9:
        raise GeometryError("mesh has zero size", where=str(path))
    return MeshInfo(path=path.resolve(), format=fmt, content_hash=content_hash(path),
                    bbox_min=bmin, bbox_max=bmax, vertices=extent_points(vertices))


# The most points a mesh's extent is judged by per pose: a convex hull of more (a
# dense sphere's every vertex is on it) is replaced by the bounding box's corners.
MAX_EXTENT_POINTS = 4096
# The hull is computed for at most this many vertices (qhull: 0.4 s for 40k points, 8 s
# for 655k on 2 cores); a denser mesh goes to the bounding box's corners at once.
MAX_HULL_INPUT = 200_000


def extent_points(points: np.ndarray) -> np.ndarray:
    """Points (N, 3) whose convex hull holds ``points``, for the tests made per pose: the
    points on their convex hull (then exact: a half-space holds all points iff it holds
    these, and a pinhole's pixel coordinate and a norm take their extremes at them), or,
    where the hull has more than ``MAX_EXTENT_POINTS`` vertices (or the mesh more than
    ``MAX_HULL_INPUT``), the 8 corners of the bounding box (conservative: a box a little
    larger, never one that cuts the mesh)."""
    if len(points) <= MAX_EXTENT_POINTS:
        return points
    hull = points
    if len(points) <= MAX_HULL_INPUT:
        from scipy.spatial import ConvexHull, QhullError

        try:
            hull = points[np.sort(ConvexHull(points).vertices)]
        except (QhullError, ValueError):  # flat: the box's corners hold it too
            pass
    if len(hull) <= MAX_EXTENT_POINTS:
        return hull
    lo, hi = points.min(axis=0), points.max(axis=0)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


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
