"""``jobs.yaml`` (manifest version 1): parsing and whole-manifest validation.

    version: 1
    defaults: {renderer: physical, resolution: [512, 512], shading_radius: 1.0, seed: 469}
    scenes:
      kitchen:
        image: scenes/kitchen.png        # sRGB PNG/JPEG or linear EXR
        fov_deg: 50                      # horizontal; or K: [[fx,0,cx],[0,fy,cy],[0,0,1]]
        depth: scenes/kitchen_depth.exr  # provided maps, or an estimator mapping
        normals: scenes/kitchen_normals.exr
        albedo: scenes/kitchen_albedo.exr
    objects:
      chair: {mesh: objects/chair.glb}   # or {bundle: DIR} or {image: PNG, mask: PNG}
    jobs:
      - {scene: kitchen, object: chair, pose: {position: [0.1, -0.9, -3.0], rotation_deg: [0, 35, 0], height: 0.9}}
      - {scene: kitchen, object: chair, placement: {pixel: [300, 410], yaw_deg: 20, height: 0.9}}

Paths are relative to the manifest. Every problem is collected with its line and its
path in the YAML, and reported together before anything renders.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.blender import DEFAULT_SAMPLES
from zcomp_cli.camera import K_from_value
from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.errors import ManifestError
from zcomp_cli.imageio import verify_image
from zcomp_cli.limits import MAX_NAME_LEN, pixel_budget_problem, shorten, type_name
from zcomp_cli.pose import Pose
from zcomp_cli.yamlloc import LocDict, line_of, load_yaml

MESH_EXTS = {".obj", ".glb", ".gltf", ".ply", ".stl"}
IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff"}
MAP_CHANNELS = {"depth": 1, "normals": 3, "albedo": 3, "roughness": 1, "metallic": 1}
DEFAULT_RADIUS = 1.0
NAME_RE = re.compile(r"[A-Za-z0-9_.\-]+")  # matched whole (fullmatch: '$' would let a final newline in)
# A name that reads as a --jobs index or range ("4", "0-3") would make --jobs ambiguous.
INDEX_LIKE_RE = re.compile(r"[0-9]+(-[0-9]+)?")
MIN_SCENE_SIDE = 2  # the estimators' finite differences need two pixels each way
MAX_SEED = 2**32 - 1  # numpy and torch generators both take [0, 2**32)
# Files zcomp writes at the top of an output folder: no job may be named like them
# (summary.json and every shard's summary.shard-I-of-N.json: summary*.json).
# what zcomp writes at the top of an output folder (eval's tables, `zcomp report`'s page,
# `zcomp preview-light`'s sheets, each scene's fitted light): no job folder may take these names
RESERVED_OUTPUT_NAMES = {"summary.json", "eval.csv", "eval.json", "report.html", "report_thumbs", "preview", "lights"}
RESERVED_OUTPUT_RE = re.compile(r"summary.*\.json", re.I)
# Blender renders no image smaller than this on a side (mesh objects are rendered at
# the scene's working size).
MIN_RENDER_SIDE = 4


def name_problem(name) -> str | None:
    """Why ``name`` cannot be a folder name inside an output root (None if it can).

    Names become ``OUT/<name>/``: only letters, digits, '_', '-' and '.'; not '.' or
    '..' (or any leading dot: hidden names clash with zcomp's temporary files), not a
    file zcomp writes at the top of OUT, and at most MAX_NAME_LEN characters."""
    if not isinstance(name, str) or not name:
        return f"expected a name, got {type_name(name)} {shorten(name)}"
    if len(name) > MAX_NAME_LEN:
        return f"{shorten(name, 40)} is {len(name)} characters long (at most {MAX_NAME_LEN})"
    if not NAME_RE.fullmatch(name):
        return f"{shorten(name)} may only use letters, digits, '_', '-' and '.' (no path separators)"
    if name.startswith("."):
        return f"{name!r} may not start with '.' (names like '.', '..' and hidden names are refused)"
    if name.lower() in RESERVED_OUTPUT_NAMES or RESERVED_OUTPUT_RE.fullmatch(name):
        return f"{name!r} is the name of a file zcomp writes in the output folder"
    return None


def job_name_problem(name) -> str | None:
    """``name_problem``, and a job name may not read as a ``--jobs`` index or range."""
    bad = name_problem(name)
    if bad is None and INDEX_LIKE_RE.fullmatch(name):
        bad = f"{name!r} reads as a job index or range: --jobs {name} would be ambiguous"
    return bad


@dataclass
class RendererSpec:
    name: str = "physical"
    settings: dict = field(default_factory=dict)


@dataclass
class Defaults:
    renderer: RendererSpec = field(default_factory=RendererSpec)
    resolution: tuple[int, int] | None = None  # (W, H); None = the scene's own size
    shading_radius: float = DEFAULT_RADIUS
    seed: int = DEFAULT_SEED
    samples: int = DEFAULT_SAMPLES  # Cycles samples for object passes


@dataclass
class SceneSpec:
    name: str
    image: Path
    width: int
    height: int
    fov_deg: float | None = None
    K: np.ndarray | None = None
    maps: dict[str, Path] = field(default_factory=dict)  # provided map files
    estimators: dict[str, dict] = field(default_factory=dict)  # map -> estimator spec
    light: object | None = None  # the light tree (lightparams.LightParams; pipeline/lightspec.py); None: estimated
    # every file the scene's settings name (the light's probe...), as the manifest
    # resolved them: job fingerprints hash their contents (pipeline/fingerprint.py)
    setting_files: list[Path] = field(default_factory=list)


def scene_camera(spec: SceneSpec, resolution: tuple[int, int] | None, native: tuple[int, int] | None = None):
    """The scene's ``Camera`` at the working ``resolution`` (W, H; None = the image's own
    size), from its K or horizontal FOV, without reading its pixels. ``native`` is the
    image's (W, H) when known; else the manifest's, else the image file's header."""
    from zcomp_cli.camera import DEFAULT_FOV_DEG, Camera
    from zcomp_cli.errors import InputError

    if native is None:
        native = (spec.width, spec.height)
        if not (native[0] and native[1]):
            from zcomp_cli.imageio import image_header

            try:
                native = image_header(spec.image)[:2]
            except ValueError as exc:
                raise InputError(f"cannot read image: {exc}", where=str(spec.image)) from exc
    w0, h0 = (int(v) for v in native)
    if spec.K is not None:
        camera = Camera(spec.K, w0, h0)
    else:
        camera = Camera.from_fov(spec.fov_deg if spec.fov_deg is not None else DEFAULT_FOV_DEG, w0, h0)
    size = resolution or (w0, h0)
    return camera.resized(*size) if size != (w0, h0) else camera


@dataclass
class ObjectSpec:
    name: str
    kind: str  # "mesh" | "bundle" | "image"
    mesh: Path | None = None
    bundle: Path | None = None
    image: Path | None = None
    mask: Path | None = None


@dataclass
class Placement:
    """``placement.pixel`` is given, and validated, in the scene image's own (native)
    pixels: ``[x, y] = [column, row]``, continuous coordinates with pixel centres at
    +0.5. ``pixel`` holds it scaled to the working size (``defaults.resolution``), the
    frame every map of the job is in; ``pixel_native`` keeps the value as written."""

    pixel: tuple[float, float]  # [x, y] = [column, row], working size
    yaw_deg: float = 0.0
    height: float | None = None
    scale: float = 1.0
    pixel_native: tuple[float, float] | None = None


@dataclass
class JobSpec:
    index: int
    name: str  # output folder name
    scene: str
    object: str
    pose: Pose | None = None
    placement: Placement | None = None
    reference: Path | None = None
    shading_radius: float = DEFAULT_RADIUS
    seed: int = DEFAULT_SEED
    line: int | None = None


@dataclass
class Manifest:
    path: Path
    defaults: Defaults
    scenes: dict[str, SceneSpec]
    objects: dict[str, ObjectSpec]
    jobs: list[JobSpec]

    @property
    def root(self) -> Path:
        return self.path.parent


class _Problems:
    def __init__(self, path: Path):
        self.path = path
        self.items: list[str] = []

    def add(self, container, key, where: str, msg: str):
        line = line_of(container, key)
        loc = f"{self.path.name}:{line}" if line else self.path.name
        self.items.append(f"{loc}: {where}: {msg}")


def _check_keys(d, allowed: set[str], where: str, probs: _Problems, required=()):
    for k in d:
        if k not in allowed:
            probs.add(d, k, f"{where}.{k}", f"unknown key (allowed: {', '.join(sorted(allowed))})")
    for k in required:
        if k not in d:
            probs.add(d, None, where, f"missing required key {k!r}")


def _num(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def special_file_problem(p: Path, want: str = "file") -> str | None:
    """Why ``p`` (which exists) cannot be read as a ``want`` ("file" or "folder"): a
    FIFO, a device or a socket would hang a reader or be read forever (``/dev/zero``),
    so only regular files (and folders where a folder is expected) are taken."""
    import stat

    try:
        mode = p.stat().st_mode
    except OSError as exc:
        return f"cannot use {shorten(str(p), 200)}: {exc.strerror}"
    if stat.S_ISDIR(mode):
        return None if want == "folder" else f"{shorten(str(p), 200)} is a folder, expected a file"
    if stat.S_ISREG(mode):
        return None if want == "file" else f"{shorten(str(p), 200)} is a file, expected a folder"
    from zcomp_cli.safe_read import file_kind

    return f"{shorten(str(p), 200)} is {file_kind(mode)}, not a regular file"


def _file(root: Path, value, container, key, where, probs, exts=None, want: str = "file") -> Path | None:
    if not isinstance(value, str) or not value:
        probs.add(container, key, where, f"expected a file path, got {type_name(value)} {shorten(value)}")
        return None
    if "\0" in value or len(value) > 4096:
        probs.add(container, key, where, f"not a usable file path: {shorten(value)}")
        return None
    p = (root / value).resolve() if not Path(value).is_absolute() else Path(value)
    try:
        exists = p.exists()
    except OSError as exc:  # e.g. a name too long for the file system
        probs.add(container, key, where, f"cannot use path {shorten(value)}: {exc.strerror}")
        return None
    if not exists:
        probs.add(container, key, where, f"file not found: {shorten(str(p), 200)}")
        return None
    special = special_file_problem(p, want)
    if special:
        probs.add(container, key, where, special)
        return None
    if exts and p.suffix.lower() not in exts:
        probs.add(container, key, where, f"unsupported format {p.suffix!r} (supported: {', '.join(sorted(exts))})")
        return None
    return p


def parse_renderer(value, container, key, where, probs) -> RendererSpec | None:
    if isinstance(value, str):
        return RendererSpec(value, {})
    if isinstance(value, dict):
        if "name" not in value or not isinstance(value["name"], str):
            probs.add(container, key, where, "renderer mapping needs a 'name'")
            return None
        settings = {k: v for k, v in value.items() if k != "name"}
        return RendererSpec(value["name"], dict(settings))
    probs.add(container, key, where, f"expected a renderer name or mapping, got {shorten(value)}")
    return None


def load_manifest(path, *, check_files: bool = True) -> Manifest:
    """Load and validate a manifest; raise ManifestError listing every problem."""
    path = Path(path).resolve()
    data = load_yaml(path)
    probs = _Problems(path)
    root = path.parent
    if not isinstance(data, dict):
        raise ManifestError(f"{path.name}: the manifest must be a mapping with version, scenes, objects, jobs")
    _check_keys(data, {"version", "defaults", "scenes", "objects", "jobs"}, "manifest", probs,
                required=("scenes", "objects", "jobs"))
    version = data.get("version", 1)
    if version != 1 or isinstance(version, bool):
        probs.add(data, "version", "version",
                  f"unsupported manifest version {shorten(version)} (this zcomp reads version 1)")

    defaults = _parse_defaults(data.get("defaults") or LocDict(), data, probs)
    scenes = _parse_scenes(data.get("scenes"), data, root, probs, check_files, defaults)
    objects = _parse_objects(data.get("objects"), data, root, probs, check_files)
    jobs = _parse_jobs(data.get("jobs"), data, root, probs, scenes, objects, defaults, check_files)
    _check_cameras(data, scenes, objects, jobs, defaults, probs)
    if check_files:
        _check_renderer(data.get("defaults"), defaults.renderer, probs)
    if probs.items:
        raise ManifestError(probs.items, source=str(path))
    return Manifest(path, defaults, scenes, objects, jobs)


def _check_renderer(d, spec: RendererSpec, probs) -> None:
    """The manifest's renderer exists and takes its settings (it is built: a renderer's
    constructor checks its settings and loads nothing heavy)."""
    from zcomp_cli.errors import ZcompError
    from zcomp_cli.renderers import get_renderer

    container = d if isinstance(d, dict) and "renderer" in d else None
    try:
        get_renderer(spec.name, **spec.settings)
    except (ZcompError, TypeError, ValueError, OverflowError) as exc:
        where = "defaults.renderer" + (f" ({spec.name})" if container is None else "")
        if container is None:
            probs.items.append(f"{probs.path.name}: {where}: {exc}")
        else:
            probs.add(container, "renderer", where, str(exc))


def _parse_defaults(d, parent, probs) -> Defaults:
    out = Defaults()
    if not isinstance(d, dict):
        probs.add(parent, "defaults", "defaults", "expected a mapping")
        return out
    _check_keys(d, {"renderer", "resolution", "shading_radius", "seed", "samples"}, "defaults", probs)
    if "renderer" in d:
        r = parse_renderer(d["renderer"], d, "renderer", "defaults.renderer", probs)
        if r:
            out.renderer = r
    if "resolution" in d:
        res = d["resolution"]
        if res in (None, "native"):
            out.resolution = None
        elif (isinstance(res, list) and len(res) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in res)
              and res[0] > 0 and res[1] > 0):
            budget = pixel_budget_problem(res[0], res[1])
            if budget:
                probs.add(d, "resolution", "defaults.resolution", budget)
            elif min(res) < MIN_SCENE_SIDE:
                probs.add(d, "resolution", "defaults.resolution",
                          f"{res[0]}x{res[1]} is too small: at least {MIN_SCENE_SIDE}x{MIN_SCENE_SIDE} pixels")
            else:
                out.resolution = (int(res[0]), int(res[1]))
        else:
            probs.add(d, "resolution", "defaults.resolution",
                      f"expected [width, height] positive integers or 'native', got {shorten(res)}")
    if "shading_radius" in d:
        v = _num(d["shading_radius"])
        if v is None or v < 0:
            probs.add(d, "shading_radius", "defaults.shading_radius",
                      f"expected a number >= 0, got {shorten(d['shading_radius'])}")
        else:
            out.shading_radius = v
    if "seed" in d:
        seed = _seed(d["seed"])
        if seed is None:
            probs.add(d, "seed", "defaults.seed", f"expected an integer in [0, {MAX_SEED}], got {shorten(d['seed'])}")
        else:
            out.seed = seed
    if "samples" in d:
        v = d["samples"]
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= 100_000:
            probs.add(d, "samples", "defaults.samples", f"expected an integer in [1, 100000], got {shorten(v)}")
        else:
            out.samples = int(v)
    return out


def _seed(v) -> int | None:
    if isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_SEED:
        return int(v)
    return None


def _parse_K(value, container, key, where, probs) -> np.ndarray | None:
    flat = [v for r in value for v in (r if isinstance(r, list) else [r])] if isinstance(value, list) else None
    if flat is None or not all(_num(v) is not None for v in flat):
        # YAML booleans and quoted numbers are not numbers here either
        probs.add(container, key, where, f"expected [[fx,0,cx],[0,fy,cy],[0,0,1]] or [fx, fy, cx, cy] "
                                         f"finite numbers, got {shorten(value)}")
        return None
    try:
        K = K_from_value(value)
    except ValueError as exc:
        probs.add(container, key, where, str(exc))
        return None
    if K[0, 1] != 0 or K[1, 0] != 0:
        probs.add(container, key, where, "skewed K (K[0][1] or K[1][0] not 0) is not supported")
        return None
    return K


def _named_entries(d, parent, section: str, what: str, expected: str, probs):
    """Yield ``(name, entry, where)`` for each well-formed ``section.<name>: {...}``;
    report the malformed ones."""
    if not isinstance(d, dict) or not d:
        if section in parent:
            probs.add(parent, section, section, f"expected a non-empty mapping of {what} name -> {what}")
        return
    for name, entry in d.items():
        where = f"{section}.{shorten(name, 40) if not isinstance(name, str) or len(name) > 40 else name}"
        bad = name_problem(name)
        if bad:
            probs.add(d, name, where, f"{what} name {bad}")
        elif not isinstance(entry, dict):
            probs.add(d, name, where, f"expected a mapping with {expected}, got {type_name(entry)}")
        else:
            yield name, entry, where


def _no_depth_problem(spec: SceneSpec, jobs, defaults) -> str:
    """The refusal of a scene without depth, its suggestion fitted to the photograph
    (its size and field of view) and to its first job that stands an object of a given
    height at a pixel (``estimators.ground_suggest``)."""
    from zcomp_cli.estimators.ground_suggest import ground_plane_suggestion

    try:
        camera = scene_camera(spec, None)
    except Exception:  # noqa: BLE001 - an unreadable image is reported on its own
        return ("no depth: give a depth map file or an estimator (e.g. depth: {proxy: ground_plane, "
                "camera_height: 1.5, pitch_deg: -10}; docs/estimation.md)")
    for j in jobs if isinstance(jobs, list) else []:
        pl = j.get("placement") if isinstance(j, dict) and j.get("scene") == spec.name else None
        px, h = (pl.get("pixel"), pl.get("height")) if isinstance(pl, dict) else (None, None)
        if (isinstance(px, list) and len(px) == 2 and all(_num(v) is not None for v in px)
                and _num(h) is not None and 0 < h < 1e3 and 0 <= px[0] < camera.width and 0 <= px[1] < camera.height):
            what = f"the {h:g} m object of its first placed job at pixel [{px[0]:g}, {px[1]:g}]"
            return ground_plane_suggestion(camera, px, h, what)
    return ground_plane_suggestion(camera)


def _parse_scenes(d, parent, root, probs, check_files, defaults) -> dict[str, SceneSpec]:
    out: dict[str, SceneSpec] = {}
    for name, s, where in _named_entries(d, parent, "scenes", "scene", "at least 'image'", probs):
        _check_keys(s, {"image", "fov_deg", "K", "light", "pitch_deg", "roll_deg", "exposure", *MAP_CHANNELS}, where,
                    probs, required=("image",))
        if "fov_deg" in s and "K" in s:
            probs.add(s, "K", where, "give fov_deg or K, not both")
        for m in MAP_CHANNELS:
            if m in s and not isinstance(s[m], (str, dict)):
                probs.add(s, m, f"{where}.{m}",
                          f"expected a map file or an estimator mapping, got {type_name(s[m])} {shorten(s[m])}")
        image = _file(root, s["image"], s, "image", f"{where}.image", probs, IMAGE_EXTS) if "image" in s else None
        w = h = 0
        if image is not None and check_files:
            try:
                w, h, c = verify_image(image)
                if c not in (1, 2, 3, 4):
                    probs.add(s, "image", f"{where}.image", f"unexpected channel count {c}")
                budget = pixel_budget_problem(w, h)
                if budget:  # the image is read at its own size before any resampling
                    probs.add(s, "image", f"{where}.image", f"the image is {budget}")
                    image = None
                elif min(w, h) < MIN_SCENE_SIDE:
                    probs.add(s, "image", f"{where}.image",
                              f"the image is {w}x{h}; a scene needs at least {MIN_SCENE_SIDE}x{MIN_SCENE_SIDE} pixels")
                    image = None
            except ValueError as exc:
                probs.add(s, "image", f"{where}.image", f"cannot read image: {exc}")
                image = None
        spec = SceneSpec(name=name, image=image, width=w, height=h)
        if "fov_deg" in s:
            v = _num(s["fov_deg"])
            if v is None or not (0 < v < 180):
                probs.add(s, "fov_deg", f"{where}.fov_deg", f"expected degrees in (0, 180), got {shorten(s['fov_deg'])}")
            else:
                spec.fov_deg = v
        if "K" in s:
            spec.K = _parse_K(s["K"], s, "K", f"{where}.K", probs)
        spec.light = _parse_scene_light(s, where, probs, root, spec.setting_files, check_files)
        for m, ch in MAP_CHANNELS.items():
            if m not in s:
                continue
            v = s[m]
            if isinstance(v, dict):
                spec.estimators[m] = _parse_estimator(m, v, s, f"{where}.{m}", root, probs, check_files)
                continue
            if not isinstance(v, str):
                continue
            p = _file(root, v, s, m, f"{where}.{m}", probs, IMAGE_EXTS)
            if p is None:
                continue
            if check_files and image is not None:
                try:
                    mw, mh, mc = verify_image(p)
                except ValueError as exc:
                    probs.add(s, m, f"{where}.{m}", f"cannot read map: {exc}")
                    continue
                if (mw, mh) != (w, h):
                    probs.add(s, m, f"{where}.{m}", f"size {mw}x{mh} differs from the image's {w}x{h}")
                if ch == 3 and mc < 3:
                    probs.add(s, m, f"{where}.{m}", f"expected 3 channels, found {mc}")
                if ch == 1 and mc not in (1, 2, 3, 4):
                    probs.add(s, m, f"{where}.{m}", f"unexpected channel count {mc}")
            spec.maps[m] = p
        if "depth" not in spec.maps and "depth" not in spec.estimators and "depth" not in s:
            probs.add(s, None, where, _no_depth_problem(spec, parent.get("jobs"), defaults))
        if defaults.resolution is not None and image is not None and w and h:
            W, H = defaults.resolution
            if abs(W / H - w / h) > 0.01 * (w / h):
                probs.add(parent.get("defaults", parent), "resolution", "defaults.resolution",
                          f"{W}x{H} does not have the aspect ratio of scene {name!r} ({w}x{h}); "
                          "use a matching size or 'native'")
        out[name] = spec
    return out


def _parse_estimator(name, spec, container, where, root, probs, check_files) -> dict:
    """An estimator mapping (``depth: {model: DIR}``...): its keys and values checked by
    the estimators' own table, ``model`` resolved against the manifest's folder and
    required to be a folder (its files are checked when it is loaded, naming each)."""
    from zcomp_cli.estimators.specs import estimator_problems

    for key, msg in estimator_problems(name, spec):
        probs.add(spec if key in spec else container, key if key in spec else name,
                  f"{where}.{key}" if key else where, msg)
    out = dict(spec)
    model = spec.get("model")
    if isinstance(model, str) and model and "\0" not in model:
        p = Path(model).expanduser()
        p = p if p.is_absolute() else (root / p).resolve()
        if check_files and not p.is_dir():
            probs.add(spec, "model", f"{where}.model",
                      f"model folder not found: {shorten(str(p), 200)} (a saved diffusers pipeline or "
                      "transformers model; nothing is downloaded)")
        elif check_files:
            from zcomp_cli.estimators.weights import folder_problem

            bad = folder_problem(p, f"{name} model")
            if bad:
                probs.add(spec, "model", f"{where}.model", bad)
        out["model"] = str(p)
    return out


def _probe_shape_problem(path: Path) -> str | None:
    """Why a probe file is not an equirectangular map (from its header alone): it must
    be twice as wide as high. Refused rather than resampled: a 1:1 or 1:200 image is a
    cube face, a mirror ball (``type: chrome_ball``) or a crop, not a map of every
    direction, and stretching it would light the scene from the wrong places."""
    from zcomp_cli.equirect import aspect_ok
    from zcomp_cli.imageio import image_header

    try:
        w, h, _ = image_header(path)
    except ValueError as exc:
        return f"cannot read the probe: {exc}"
    if not aspect_ok(w, h):
        return (f"the probe is {w}x{h}: an equirectangular (latitude-longitude) map is twice as wide as high "
                "(a mirror-ball photograph is type: chrome_ball)")
    return None


def _no_light(path: Path) -> str | None:
    """Why an HDR probe cannot light anything (all 0, negative or not finite: the object
    would be drawn black and the light's direction read as [0, 0, 0]), else None."""
    from zcomp_cli.errors import ZcompError
    from zcomp_cli.imageio import read_image

    try:
        img = read_image(path)
    except ZcompError as exc:
        return f"cannot read the probe: {exc}"
    lit = np.isfinite(img) & (img > 0)
    if not lit.any():
        return "the probe holds no light (every pixel is 0, negative or not finite)"
    return None


def _parse_scene_light(s, where, probs, root, files: list, check_files: bool = True):
    """The scene's light tree for the renderer (``zcomp_cli.scene.lightparams.LightParams``)
    from ``light``, ``pitch_deg``/``roll_deg`` and ``exposure`` when given
    (``pipeline/lightspec.py``), or from the light file ``light`` names (those keys in a
    YAML file of their own: a light zcomp wrote, given back; its paths relative to it);
    None when the scene gives none of them (the light is estimated, world up read off
    the support). Every file the light names is appended to ``files`` (the resume
    fingerprint hashes them)."""
    from zcomp_cli.pipeline.lightspec import (LIGHT_FILE_KEYS, PROBE_EXTS, check_given_directions, parse_exposure,
                                              parse_light, parse_tilt, scene_light)

    src, lroot, lprobs = s, root, probs
    if isinstance(s.get("light"), str):  # a light file
        lp = _file(root, s["light"], s, "light", f"{where}.light", probs, {".yaml", ".yml"})
        if lp is None:
            return None
        both = sorted(k for k in LIGHT_FILE_KEYS - {"light"} if k in s)
        if both:
            probs.add(s, both[0], f"{where}.{both[0]}", f"give {', '.join(both)} in the light file {lp.name} or "
                                                        "here, not both")
            return None
        files.append(lp)
        lprobs = _Problems(lp)
        try:
            src = load_yaml(lp)
        except ManifestError as exc:
            probs.add(s, "light", f"{where}.light", f"cannot read the light file: {exc}")
            return None
        if not isinstance(src, dict) or "light" not in src:
            probs.add(s, "light", f"{where}.light", f"{lp.name} is no light file: expected a mapping with 'light' "
                                                    "(and pitch_deg, roll_deg, exposure)")
            return None
        _check_keys(src, LIGHT_FILE_KEYS, lp.name, lprobs)
        lroot, where = lp.parent, lp.name

    def add(container, key, w, msg):  # problems without a container sit on 'light'
        lprobs.add(src if container is None else container, "light" if container is None else key, w, msg)

    def resolve(container, key, w, exts=PROBE_EXTS):  # a light probe file, relative to the manifest (its file)
        p = _file(lroot, container[key], container, key, w, lprobs, exts)
        if p is not None and check_files and exts is PROBE_EXTS:
            bad = _probe_shape_problem(p)
            if bad:
                lprobs.add(container, key, w, bad)
                return None
        if p is not None and check_files:
            dark = _no_light(p)
            if dark:
                lprobs.add(container, key, w, dark)
                return None
        if p is not None:
            files.append(p)
        return p

    tilt = parse_tilt(src, where, lambda c, k, w, m: lprobs.add(c, k, w, m))
    exposure = parse_exposure(src, where, lambda c, k, w, m: lprobs.add(c, k, w, m))
    params = parse_light(src["light"], f"{where}.light", add, resolve) if "light" in src else None
    check_given_directions(params, tilt, f"{where}.light", add)
    if lprobs is not probs:
        probs.items += lprobs.items
    return scene_light(params, tilt, exposure)


def _parse_objects(d, parent, root, probs, check_files) -> dict[str, ObjectSpec]:
    out: dict[str, ObjectSpec] = {}
    for name, o, where in _named_entries(d, parent, "objects", "object",
                                         "'mesh', 'bundle' or 'image' + 'mask'", probs):
        _check_keys(o, {"mesh", "bundle", "image", "mask"}, where, probs)
        kinds = [k for k in ("mesh", "bundle", "image") if k in o]
        if len(kinds) != 1:
            probs.add(o, None, where, "give exactly one of 'mesh', 'bundle' or 'image' (+ 'mask')")
            continue
        kind = kinds[0]
        spec = ObjectSpec(name=name, kind=kind)
        if kind == "mesh":
            spec.mesh = _file(root, o["mesh"], o, "mesh", f"{where}.mesh", probs, MESH_EXTS)
            if spec.mesh is not None and check_files:
                from zcomp_cli.blender.meshes import mesh_file_problems

                for problem in mesh_file_problems(spec.mesh):
                    probs.add(o, "mesh", f"{where}.mesh", problem)
                    spec.mesh = None
        elif kind == "bundle":
            p = _file(root, o["bundle"], o, "bundle", f"{where}.bundle", probs, want="folder")
            if p is not None and not (p / "meta.json").is_file():
                probs.add(o, "bundle", f"{where}.bundle", f"not an intrinsics bundle (no meta.json in {p})")
                p = None
            if p is not None:
                special = next((x for x in (special_file_problem(f, "folder" if f.is_dir() else "file")
                                            for f in sorted(p.iterdir())) if x), None)
                if special:
                    probs.add(o, "bundle", f"{where}.bundle", special)
                    p = None
            spec.bundle = p
        else:
            spec.image = _file(root, o["image"], o, "image", f"{where}.image", probs, IMAGE_EXTS)
            if "mask" not in o:
                probs.add(o, None, where, "an image object needs a 'mask'")
            else:
                spec.mask = _file(root, o["mask"], o, "mask", f"{where}.mask", probs, IMAGE_EXTS)
            if check_files:
                sizes = {}
                for key in ("image", "mask"):
                    p = getattr(spec, key)
                    if p is None:
                        continue
                    try:
                        ow, oh, _ = verify_image(p)
                    except ValueError as exc:
                        probs.add(o, key, f"{where}.{key}", f"cannot read image: {exc}")
                        setattr(spec, key, None)
                        continue
                    budget = pixel_budget_problem(ow, oh)
                    if budget:
                        probs.add(o, key, f"{where}.{key}", f"the image is {budget}")
                        setattr(spec, key, None)
                        continue
                    sizes[key] = (ow, oh)
                if len(sizes) == 2 and sizes["image"] != sizes["mask"]:
                    (iw, ih), (mw, mh) = sizes["image"], sizes["mask"]
                    probs.add(o, "mask", f"{where}.mask", f"the mask is {mw}x{mh}, the image {iw}x{ih}")
                elif "mask" in sizes and _empty_mask(spec.mask):
                    probs.add(o, "mask", f"{where}.mask", "the mask selects no pixel (all 0: nothing to composite)")
        out[name] = spec
    return out


def _empty_mask(path: Path) -> bool:
    from zcomp_cli.imageio import read_alpha_or_grey

    try:
        return not (read_alpha_or_grey(path) > 0).any()
    except Exception:  # noqa: BLE001 - unreadable: the header check has said so, or the job will
        return False


def _parse_jobs(d, parent, root, probs, scenes, objects, defaults, check_files) -> list[JobSpec]:
    out: list[JobSpec] = []
    if not isinstance(d, list) or not d:
        if "jobs" in parent:
            probs.add(parent, "jobs", "jobs", "expected a non-empty list of jobs")
        return out
    names: dict[str, int] = {}
    for i, j in enumerate(d):
        where = f"jobs[{i}]"
        if not isinstance(j, dict):
            probs.add(d, i, where, "expected a mapping with scene, object and pose or placement")
            continue
        _check_keys(j, {"scene", "object", "pose", "placement", "output", "reference", "shading_radius", "seed"},
                    where, probs, required=("scene", "object"))
        scene = j.get("scene")
        obj = j.get("object")
        # A list or mapping here is unhashable: check the type before looking it up.
        if "scene" in j and (not isinstance(scene, str) or scene not in scenes):
            probs.add(j, "scene", f"{where}.scene",
                      f"unknown scene {shorten(scene)} (defined: {shorten(', '.join(map(str, scenes)), 200) or 'none'})")
            scene = None
        if "object" in j and (not isinstance(obj, str) or obj not in objects):
            probs.add(j, "object", f"{where}.object",
                      f"unknown object {shorten(obj)} (defined: {shorten(', '.join(map(str, objects)), 200) or 'none'})")
            obj = None
        job = JobSpec(index=i, name="", scene=str(scene), object=str(obj), line=line_of(d, i),
                      shading_radius=defaults.shading_radius, seed=defaults.seed)
        has_pose, has_place = "pose" in j, "placement" in j
        if has_pose == has_place:
            probs.add(j, None, where, "give exactly one of 'pose' (camera frame) or 'placement' (pixel)")
        elif has_pose:
            try:
                job.pose = Pose.from_dict(j["pose"], where=f"{where}.pose")
            except ManifestError as exc:
                for problem in exc.problems:
                    probs.items.append(f"{probs.path.name}:{line_of(j, 'pose')}: {problem}")
        else:
            job.placement = _parse_placement(j["placement"], j, f"{where}.placement", probs, scenes.get(scene),
                                             defaults.resolution)
        if "output" in j:
            bad = job_name_problem(j["output"])
            if bad:
                probs.add(j, "output", f"{where}.output", f"expected a folder name inside --out: {bad}")
            else:
                job.name = j["output"]
        if "reference" in j:
            job.reference = _file(root, j["reference"], j, "reference", f"{where}.reference", probs, IMAGE_EXTS)
        if "shading_radius" in j:
            v = _num(j["shading_radius"])
            if v is None or v < 0:
                probs.add(j, "shading_radius", f"{where}.shading_radius",
                          f"expected a number >= 0, got {shorten(j['shading_radius'])}")
            else:
                job.shading_radius = v
        if "seed" in j:
            seed = _seed(j["seed"])
            if seed is None:
                probs.add(j, "seed", f"{where}.seed", f"expected an integer in [0, {MAX_SEED}], got {shorten(j['seed'])}")
            else:
                job.seed = seed
        ospec = objects.get(obj) if isinstance(obj, str) else None
        if ospec is not None and ospec.kind == "image":  # a photo: no 3D pose, no scale of its own
            if has_pose and not has_place:
                probs.add(j, "pose", f"{where}.pose",
                          f"image object {obj!r} needs a 'placement' (pixel, height), not a 'pose'")
            elif has_place and isinstance(j.get("placement"), dict) and "height" not in j["placement"]:
                probs.add(j, "placement", f"{where}.placement",
                          f"image object {obj!r} needs 'placement.height' (metres): a photo has no scale")
        if not job.name:
            job.name = f"{i:03d}_{job.scene}_{job.object}"
        if job.name in names:
            probs.add(j, "output", f"{where}.output", f"output {job.name!r} is also used by jobs[{names[job.name]}]")
        names[job.name] = i
        out.append(job)
    return out


def _parse_placement(p, parent, where, probs, scene: SceneSpec | None, resolution=None) -> Placement | None:
    if not isinstance(p, dict):
        probs.add(parent, "placement", where, "expected a mapping {pixel: [x, y], yaw_deg, height}")
        return None
    _check_keys(p, {"pixel", "yaw_deg", "height", "scale"}, where, probs, required=("pixel",))
    px = p.get("pixel")
    if "pixel" in p:
        if not (isinstance(px, list) and len(px) == 2 and all(_num(v) is not None for v in px)):
            probs.add(p, "pixel", f"{where}.pixel", f"expected [x, y] (column, row), got {shorten(px)}")
            return None
        if scene is not None and scene.width and not (0 <= px[0] < scene.width and 0 <= px[1] < scene.height):
            probs.add(p, "pixel", f"{where}.pixel",
                      f"{shorten(px)} is outside the {scene.width}x{scene.height} image of scene {scene.name!r} "
                      "(pixels of the image file, before any resolution change)")
    yaw = _num(p.get("yaw_deg", 0.0))
    if yaw is None:
        probs.add(p, "yaw_deg", f"{where}.yaw_deg", f"expected a number (degrees), got {shorten(p.get('yaw_deg'))}")
        yaw = 0.0
    height = p.get("height")
    if height is not None and (_num(height) is None or height <= 0):
        probs.add(p, "height", f"{where}.height", f"expected metres > 0, got {shorten(height)}")
        height = None
    scale = p.get("scale", 1.0)
    if _num(scale) is None or scale <= 0:
        probs.add(p, "scale", f"{where}.scale", f"expected a number > 0, got {shorten(scale)}")
        scale = 1.0
    if px is None:
        return None
    native = (float(px[0]), float(px[1]))
    work = native
    if resolution is not None and scene is not None and scene.width and scene.height:
        work = (native[0] * resolution[0] / scene.width, native[1] * resolution[1] / scene.height)
    return Placement(pixel=work, yaw_deg=float(yaw), height=None if height is None else float(height),
                     scale=float(scale), pixel_native=native)


def _check_cameras(data, scenes, objects, jobs, defaults, probs) -> None:
    """Mesh objects are rendered by Blender with square pixels: a scene whose working
    camera has fx != fy cannot take them. Said here, on the scene's K (the camera is
    the cause, not the object), before anything renders."""
    users: dict[str, list[int]] = {}
    for job in jobs:
        o = objects.get(job.object)
        if o is not None and o.kind == "mesh" and job.scene in scenes:
            users.setdefault(job.scene, []).append(job.index)
    for name, idx in users.items():
        sc = scenes[name]
        shown = ", ".join(f"jobs[{i}]" for i in idx[:5]) + (" ..." if len(idx) > 5 else "")
        W, H = defaults.resolution or (sc.width, sc.height)
        if W and H and min(W, H) < MIN_RENDER_SIDE:
            where, container = ("defaults.resolution", data.get("defaults")) if defaults.resolution else (
                f"scenes.{name}.image", data["scenes"][name])
            probs.add(container, "resolution" if defaults.resolution else "image", where,
                      f"the working size of scene {name!r} is {W}x{H}: Blender renders mesh objects at least "
                      f"{MIN_RENDER_SIDE}x{MIN_RENDER_SIDE} pixels ({shown} use a mesh object in this scene)")
            continue
        if sc.K is None:
            continue
        fx, fy = sc.K[0, 0], sc.K[1, 1]
        if defaults.resolution is not None and sc.width and sc.height:
            fx *= defaults.resolution[0] / sc.width
            fy *= defaults.resolution[1] / sc.height
        if abs(fx - fy) > 1e-6 * max(fx, fy):
            entry = data["scenes"][name]
            probs.add(entry, "K", f"scenes.{name}.K",
                      f"non-square pixels (fx={fx:g} != fy={fy:g}) at the working size: Blender renders "
                      f"mesh objects with square pixels ({shown} use a mesh object in this scene)")

