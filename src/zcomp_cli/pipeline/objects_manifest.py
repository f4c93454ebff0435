"""``objects.yaml`` for ``zcomp render-intrinsics``: parsing and validation.

    objects:                      # name -> mesh path (or {mesh: path}), relative to the YAML
      chair: meshes/chair.glb
    cameras:                      # name -> fov_deg or K, and resolution [W, H]
      main: {fov_deg: 50, resolution: [512, 512]}
      calib: {K: [[500, 0, 320], [0, 500, 240], [0, 0, 1]], resolution: [640, 480]}
    renders:                      # one bundle each, written to OUT/<name>/
      - {object: chair, camera: main, pose: {position: [0, -1, -3], rotation_deg: [0, 30, 0], height: 0.9},
         name: chair_front}       # name optional; default <object>_<index>

Problems are located as in ``jobs.yaml`` (``objects.yaml:12: renders[1].pose: ...``) with
the same machinery (``pipeline.manifest``). Structural problems are raised together;
a problem of one item's values (a camera that cannot be built) becomes that item's
error, so the other items still render.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from zcomp_cli.camera import DEFAULT_FOV_DEG, Camera, K_from_value
from zcomp_cli.errors import ManifestError
from zcomp_cli.pipeline.manifest import _check_keys, _num, _Problems, name_problem
from zcomp_cli.pose import Pose
from zcomp_cli.yamlloc import LocDict, line_of, load_yaml

TOP_KEYS = {"objects", "cameras", "renders"}
CAMERA_KEYS = {"fov_deg", "K", "resolution"}
RENDER_KEYS = {"object", "camera", "pose", "name"}
DEFAULT_RESOLUTION = (512, 512)


@dataclass
class RenderItem:
    """One output folder to produce; ``error`` set when it cannot even be requested."""

    name: str
    mesh: Path | None = None
    pose: Pose | None = None
    camera: Camera | None = None
    error: str | None = None


def camera_from_spec(fov_deg, K, resolution, where: str) -> tuple[Camera | None, str | None]:
    """A Camera from a FOV (default 50°) or K and a ``(W, H)`` resolution; returns
    ``(camera, None)`` or ``(None, message naming where)``."""
    try:
        from zcomp_cli.limits import pixel_budget_problem

        from zcomp_cli.pipeline.manifest import MIN_RENDER_SIDE

        w, h = (int(v) for v in resolution)
        if w <= 0 or h <= 0:
            return None, f"{where}: resolution must be positive, got {w}x{h}"
        if min(w, h) < MIN_RENDER_SIDE:
            return None, (f"{where}: resolution {w}x{h} is too small: Blender renders at least "
                          f"{MIN_RENDER_SIDE}x{MIN_RENDER_SIDE} pixels")
        budget = pixel_budget_problem(w, h)
        if budget:  # refused before Blender allocates anything
            return None, f"{where}: resolution {budget}"
        if K is not None:
            return Camera(K_from_value(K), w, h), None
        fov = DEFAULT_FOV_DEG if fov_deg is None else float(fov_deg)
        if not 0 < fov < 180:  # (NaN fails this too)
            return None, f"{where}: fov_deg must be degrees in (0, 180), got {fov_deg}"
        return Camera.from_fov(fov, w, h), None
    except (TypeError, ValueError) as exc:
        return None, f"{where}: invalid camera: {exc}"


def _resolution(v) -> bool:
    return (isinstance(v, list) and len(v) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) for x in v))


def load_objects_manifest(path) -> list[RenderItem]:
    """Parse and validate an objects YAML; raise ManifestError listing every problem."""
    path = Path(path).resolve()
    doc = load_yaml(path)  # ManifestError naming the file (and the line of a syntax error)
    if not isinstance(doc, dict):
        raise ManifestError("top level must be a mapping with objects, cameras, renders", source=str(path))
    probs = _Problems(path)
    for k in doc:
        if k not in TOP_KEYS:
            probs.add(doc, k, str(k), f"unknown key (allowed: {', '.join(sorted(TOP_KEYS))})")
    for k in sorted(TOP_KEYS - set(doc)):
        probs.add(doc, None, k, "required")
    objects = doc.get("objects")
    cameras = doc.get("cameras")
    renders = doc.get("renders")
    for key, value, kind in (("objects", objects, dict), ("cameras", cameras, dict), ("renders", renders, list)):
        if key in doc and (not isinstance(value, kind) or not value):
            probs.add(doc, key, key, f"expected a non-empty {'mapping of name -> entry' if kind is dict else 'list'}")
    objects = objects if isinstance(objects, dict) else LocDict()
    cameras = cameras if isinstance(cameras, dict) else LocDict()
    renders = renders if isinstance(renders, list) else []

    meshes: dict[str, Path] = {}
    for name, entry in objects.items():
        where = f"objects.{name}"
        container, key = objects, name
        if isinstance(entry, dict):
            _check_keys(entry, {"mesh"}, where, probs, required=("mesh",))
            container, key, entry = entry, "mesh", entry.get("mesh")
            where = f"{where}.mesh"
        if not isinstance(entry, str) or not entry:
            probs.add(container, key, where, "expected a mesh path (or {mesh: path})")
            continue
        # A missing or unreadable mesh fails its renders only (reported by the renderer).
        p = Path(entry).expanduser()
        meshes[str(name)] = p if p.is_absolute() else path.parent / p

    cams: dict[str, tuple] = {}
    for name, entry in cameras.items():
        where = f"cameras.{name}"
        if not isinstance(entry, dict):
            probs.add(cameras, name, where, "expected a mapping with fov_deg or K, and resolution")
            continue
        _check_keys(entry, CAMERA_KEYS, where, probs)
        if "fov_deg" in entry and "K" in entry:
            probs.add(entry, "K", where, "give fov_deg or K, not both")
        if not _resolution(entry.get("resolution")):
            probs.add(entry, "resolution", f"{where}.resolution", "required, [width, height] in pixels")
            continue
        K = entry.get("K")
        if K is not None:
            try:
                K = K_from_value(K)
            except ValueError as exc:
                probs.add(entry, "K", f"{where}.K", str(exc))
                continue
        fov = entry.get("fov_deg")
        if fov is not None and _num(fov) is None:
            probs.add(entry, "fov_deg", f"{where}.fov_deg", "expected a number of degrees")
            continue
        cams[str(name)] = (fov, K, entry["resolution"])

    items: list[RenderItem] = []
    names: dict[str, int] = {}
    for i, r in enumerate(renders):
        where = f"renders[{i}]"
        if not isinstance(r, dict):
            probs.add(renders, i, where, "expected a mapping with object, camera, pose")
            continue
        _check_keys(r, RENDER_KEYS, where, probs, required=("object", "camera", "pose"))
        obj, cam = r.get("object"), r.get("camera")
        if "object" in r and str(obj) not in objects:
            probs.add(r, "object", f"{where}.object", f"unknown object {obj!r} (known: {sorted(map(str, objects))})")
        if "camera" in r and str(cam) not in cameras:
            probs.add(r, "camera", f"{where}.camera", f"unknown camera {cam!r} (known: {sorted(map(str, cameras))})")
        pose = None
        if "pose" in r:
            try:
                pose = Pose.from_dict(r["pose"], where=f"{where}.pose")
            except ManifestError as exc:
                for problem in exc.problems:
                    probs.items.append(f"{path.name}:{line_of(r, 'pose')}: {problem}")
        name = str(r.get("name") or f"{obj}_{i:03d}")
        bad = name_problem(name)
        if bad:
            probs.add(r, "name", f"{where}.name", f"not a plain folder name inside --out: {bad}")
        elif name in names:
            probs.add(r, "name", f"{where}.name", f"{name!r} already used by renders[{names[name]}]")
        names.setdefault(name, i)
        if str(obj) not in meshes or str(cam) not in cams or pose is None:
            continue
        camera, err = camera_from_spec(*cams[str(cam)], where=f"cameras.{cam}")
        items.append(RenderItem(name=name, mesh=meshes[str(obj)], pose=pose, camera=camera,
                                error=f"{where}: {err}" if err else None))
    if probs.items:
        raise ManifestError(probs.items, source=str(path))
    return items
