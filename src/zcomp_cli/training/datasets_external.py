"""Training datasets in the OpenRooms and InteriorVerse layouts (docs/zerocomp.md,
"Training datasets").

Each sample has exactly the structure of :class:`~zcomp_cli.training.datasets.ZcompBundleDataset`
samples, so the trainer needs no change: a dict of float32 arrays

* ``image``   (H, W, 3) linear RGB, exposed and clipped to [0, 1] (see ``exposure``);
* ``depth``   (H, W) metres, invalid = 0;
* ``normals`` (H, W, 3) unit camera-frame normals (zcomp/OpenGL convention), 0 where unknown;
* ``albedo``  (H, W, 3) linear RGB in [0, 1];
* ``roughness``, ``metallic`` (H, W) in [0, 1], only when the dataset needs material
  (13-channel training).

Normals: both datasets store the vector that the official ZeroComp training fed to the
network unchanged (``e * 0.5 + 0.5``), in the OpenGL camera frame (x right, y up, +z toward
the viewer: OpenRooms writes (N.U, N.V, N.(-W)), W = lookat - eye), which is zcomp's own
camera frame (DESIGN.md section 4). The loaders therefore only normalise: ``n = normalize(e)``,
the inverse of :func:`zcomp_cli.conventions.camera_normals_to_conditioning`, so the
conditioning the trainer builds from a loaded sample equals the encoding stored in the file.

Every problem (missing file, unreadable file, wrong shape, NaN/Inf) raises
:class:`~zcomp_cli.errors.InputError` naming the sample and the file.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zcomp_cli.conventions import GAMMA, normalize
from zcomp_cli.errors import InputError

__all__ = [
    "OpenRoomsDataset",
    "InteriorVerseDataset",
    "read_openrooms_depth",
    "decode_official_normals",
    "expose_p95",
]

# Official OpenRooms albedo (imbaseColor) PNGs are decoded with a pure 2.2 gamma, not the
# sRGB curve (ZeroComp and Li et al. both use x ** 2.2): conventions.GAMMA.
# Exposure: the 95th percentile of the valid pixels is mapped to this value (the middle of
# the official training range 0.85-0.95, and its evaluation value), then the image is
# clipped to [0, 1] as the official loaders do. The percentile is floored so that a dark
# image is brightened at most x9 (official floor 0.1).
EXPOSURE_TARGET = 0.9
EXPOSURE_FLOOR = 0.1
EXPOSURE_PERCENTILE = 95.0
# InteriorVerse depth: millimetres; +inf (and anything at or beyond 100 m) is "no surface".
IV_DEPTH_SCALE = 1e-3
IV_DEPTH_MAX_MM = 1e5
# OpenRooms immask: 1 = geometry, 0.5 = area lights, 0 = windows / environment.
MASK_VALID = 0.9
# Visible surfaces face the camera (z > 0 in the OpenGL frame the checkpoints expect): a
# dataset whose decoded normals mostly face away is stored in another convention (e.g.
# Blender shader camera space, z forward) and would train the model upside down: warn once.
BACKFACING_WARN_FRACTION = 0.5


# ----------------------------------------------------------------------------- helpers


def decode_official_normals(encoded) -> np.ndarray:
    """Official ZeroComp normal vectors -> zcomp camera-frame unit normals.

    Args:
        encoded: (H, W, 3) vectors in the official conditioning frame, components in
            [-1, 1] (i.e. ``2 * png - 1`` for OpenRooms PNGs, the raw EXR for InteriorVerse).
    Returns:
        (H, W, 3) float32 unit normals in zcomp's camera frame; zero-length vectors stay 0.
        No axis is flipped: the official frame is zcomp's OpenGL camera frame, so
        ``camera_normals_to_conditioning(result) == normalize(encoded) * 0.5 + 0.5``.
    """
    e = np.asarray(encoded, np.float32)
    if e.ndim != 3 or e.shape[-1] != 3:
        raise InputError(f"normals must be (H, W, 3), got {e.shape}")
    return normalize(e)


def read_openrooms_depth(path) -> np.ndarray:
    """Read an OpenRooms ``imdepth_<i>.dat``: int32 height, int32 width (little-endian),
    then height*width float32 depths in metres, row-major. Returns (H, W) float32.

    Raises InputError if the file is missing, truncated, longer than its header says, or
    its header is not a plausible image size."""
    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", where=str(p))
    raw = p.read_bytes()
    if len(raw) < 8:
        raise InputError(f"depth file too short ({len(raw)} bytes) for its 8-byte header",
                         where=str(p))
    h, w = (int(v) for v in np.frombuffer(raw[:8], "<i4"))
    if not (0 < h <= 1 << 16 and 0 < w <= 1 << 16):
        raise InputError(f"depth header gives an implausible size {h}x{w}", where=str(p))
    want = 8 + 4 * h * w
    if len(raw) != want:
        raise InputError(f"depth file holds {len(raw)} bytes, its {h}x{w} header needs {want}",
                         where=str(p))
    return np.frombuffer(raw[8:], "<f4").reshape(h, w).astype(np.float32)


def expose_p95(image, valid=None, *, target: float = EXPOSURE_TARGET,
               floor: float = EXPOSURE_FLOOR) -> tuple[np.ndarray, float]:
    """Scale a linear HDR image so its 95th percentile (over ``valid`` pixels, all channels)
    lands on ``target``, then clip to [0, 1].

    Args:
        image: (H, W, 3) linear, finite, >= 0 (negatives are clipped first).
        valid: optional (H, W) bool; ignored when it holds under 1 % of the pixels.
    Returns:
        (exposed image float32 in [0, 1], scale used).
    """
    img = np.clip(np.asarray(image, np.float32), 0, None)
    vals = img
    if valid is not None and valid.sum() >= 0.01 * valid.size:
        vals = img[valid]
    p = float(np.percentile(vals, EXPOSURE_PERCENTILE)) if vals.size else 0.0
    scale = target / max(p, floor)
    return np.clip(img * scale, 0.0, 1.0).astype(np.float32), scale


def _bare(e: InputError) -> str:
    """The message of ``e`` without its ``where:`` prefix (we add our own)."""
    msg = str(e)
    return msg[len(e.where) + 2:] if e.where and msg.startswith(f"{e.where}: ") else msg


def _read(sample: str, path: Path, *, channels=None) -> np.ndarray:
    """Read a map without colour decoding; errors name the sample and the file."""
    from zcomp_cli.imageio import read_map

    if not path.is_file():
        raise InputError(f"sample {sample}: missing {path.name}", where=str(path))
    try:
        return read_map(path, channels=channels)
    except InputError as e:
        raise InputError(f"sample {sample}: cannot read {path.name}: {_bare(e)}",
                         where=str(path)) from e


def _finite(sample: str, path: Path, a: np.ndarray, where=None) -> None:
    bad = ~np.isfinite(a)
    if where is not None:
        bad &= where if bad.ndim == where.ndim else where[..., None]
    if bad.any():
        raise InputError(f"sample {sample}: {path.name} holds {int(bad.sum())} NaN/Inf value(s)",
                         where=str(path))


def _shape(sample: str, path: Path, a: np.ndarray, hw: tuple[int, int], c: int | None) -> None:
    """(H, W) when ``c`` is None, else (H, W, >= c)."""
    chans_ok = a.ndim == 2 if c is None else (a.ndim == 3 and a.shape[2] >= c)
    ok = a.shape[:2] == tuple(hw) and chans_ok
    if not ok:
        want = tuple(hw) if c is None else (*hw, c)
        raise InputError(f"sample {sample}: {path.name} has shape {a.shape}, expected {want}",
                         where=str(path))


def _raise_missing(layout: str, root: Path, missing: list[str], show: int = 10) -> None:
    """One InputError listing the first ``show`` missing files (each naming its sample)."""
    if missing:
        more = f"\n  ... and {len(missing) - show} more" if len(missing) > show else ""
        raise InputError(f"{layout} dataset {root}: {len(missing)} missing file(s):\n  "
                         + "\n  ".join(missing[:show]) + more)


def _first_channel(a: np.ndarray) -> np.ndarray:
    return a if a.ndim == 2 else a[..., 0]


class _BackfacingCheck:
    """Warns once per dataset when most decoded normals face away from the camera
    (z < 0 in zcomp's OpenGL frame). Visible surfaces cannot face away, so this means the
    files use another frame (e.g. z forward) than the official checkpoints' (DESIGN.md
    section 4): their normals must be converted before training."""

    def __init__(self, layout: str):
        self.layout, self.done = layout, False

    def __call__(self, sample: str, normals: np.ndarray) -> None:
        if self.done:
            return
        nz = normals[np.linalg.norm(normals, axis=-1) > 0.5]
        if nz.size == 0:
            return
        self.done = True
        frac = float((nz[:, 2] < 0).mean())
        if frac > BACKFACING_WARN_FRACTION:
            warnings.warn(f"{self.layout} sample {sample}: {frac:.0%} of the normals face away "
                          "from the camera (z < 0 in the OpenGL camera frame the official "
                          "checkpoints expect); the files are probably in another frame "
                          "(z forward?): convert them before training (docs/zerocomp.md, "
                          "'Training datasets')", stacklevel=3)


# ----------------------------------------------------------------------------- OpenRooms


@dataclass(frozen=True)
class _ORSample:
    name: str
    image: Path
    depth: Path
    normal: Path
    albedo: Path
    roughness: Path
    metallic: Path
    mask: Path


_OR_KINDS = {  # file prefix -> folder of the split layout
    "im": "Image", "imdepth": "Geometry", "imnormal": "Geometry",
    "imbaseColor": "Material", "imroughness": "Material", "immetallic": "Material",
    "immask": "Mask",
}
_IM_RE = re.compile(r"^im_(\d+)\.hdr$")


def _main_variant(rel: Path) -> Path:
    """mainDiffLight_xml1/scene -> main_xml1/scene: DiffLight/DiffMat renders share the
    main render's geometry (and DiffLight its materials); OpenRooms stores them once."""
    parts = [re.sub(r"^main(DiffLight|DiffMat)", "main", p) for p in rel.parts]
    return Path(*parts)


class OpenRoomsDataset:
    """OpenRooms renders (Li et al., CVPR 2021), in either layout:

    * split: ``root/Image/<split>/<scene>/im_<i>.hdr`` with ``root/Geometry/...``
      (``imdepth_<i>.dat``, ``imnormal_<i>.png``), ``root/Material/...``
      (``imbaseColor_<i>.png``, ``imroughness_<i>.png`` [, ``immetallic_<i>.png``]) and
      ``root/Mask/...`` (``immask_<i>.png``), as the OpenRooms archives and the ZeroComp
      README arrange them; a ``mainDiffLight``/``mainDiffMat`` render falls back to its
      ``main`` counterpart for files it does not have;
    * flat: every file of a view side by side in ``root/**/<scene>/``.

    Args:
        root: dataset root.
        need_material: also load roughness (``imroughness``) and metallic (``immetallic``).
        exposure: ``"p95"`` (default, as the official loader) or ``"none"`` (raw radiance,
            clipped to [0, 1]).
    Raises:
        InputError: root missing, no ``im_<i>.hdr`` found, or a view lacks a required file.
    """

    layout = "openrooms"

    def __init__(self, root, *, need_material: bool = False, exposure: str = "p95"):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"dataset root not found: {self.root}")
        if exposure not in ("p95", "none"):
            raise InputError(f"openrooms: exposure must be 'p95' or 'none', got {exposure!r}")
        self.need_material, self.exposure = need_material, exposure
        split = (self.root / "Image").is_dir()
        base = self.root / "Image" if split else self.root
        ims = sorted((p for p in base.rglob("im_*.hdr") if _IM_RE.match(p.name)),
                     key=lambda p: (str(p.parent), int(_IM_RE.match(p.name).group(1))))
        if not ims:
            raise InputError(f"openrooms dataset {self.root}: no im_<i>.hdr found under {base}")
        self.samples = [self._locate(p, base, split) for p in ims]
        self._check_files()
        self._facing = _BackfacingCheck(self.layout)

    def _locate(self, im: Path, base: Path, split: bool) -> _ORSample:
        i = _IM_RE.match(im.name).group(1)
        rel = im.parent.relative_to(base)
        name = f"{rel.as_posix()}/{i}"

        def find(prefix: str, ext: str) -> Path:
            fname = f"{prefix}_{i}.{ext}"
            if not split:
                return im.parent / fname
            first = self.root / _OR_KINDS[prefix] / rel / fname
            if first.is_file():
                return first
            alt = self.root / _OR_KINDS[prefix] / _main_variant(rel) / fname
            return alt if alt.is_file() else first

        return _ORSample(name, im, find("imdepth", "dat"), find("imnormal", "png"),
                         find("imbaseColor", "png"), find("imroughness", "png"),
                         find("immetallic", "png"), find("immask", "png"))

    def _check_files(self) -> None:
        # Fail before training starts rather than at step 5000.
        missing = []
        for s in self.samples:
            need = [s.depth, s.normal, s.albedo]
            need += [s.roughness, s.metallic] if self.need_material else []
            missing += [f"sample {s.name}: missing {p.name} (looked for {p})"
                        for p in need if not p.is_file()]
        _raise_missing("openrooms", self.root, missing)

    def __len__(self) -> int:
        return len(self.samples)

    def sample_name(self, i: int) -> str:
        return self.samples[i].name

    def __getitem__(self, i) -> dict:
        s = self.samples[i]
        n = s.name
        # 1. image (Radiance RGBE, linear) and the geometry mask
        hdr = _read(n, s.image, channels=3)
        _finite(n, s.image, hdr)
        hw = hdr.shape[:2]
        valid = None
        if s.mask.is_file():
            m = _first_channel(_read(n, s.mask))
            _shape(n, s.mask, m, hw, None)
            valid = m >= MASK_VALID
        if self.exposure == "p95":
            image, _ = expose_p95(hdr, valid)
        else:
            image = np.clip(hdr, 0, 1).astype(np.float32)
        # 2. depth (.dat, metres)
        try:
            depth = read_openrooms_depth(s.depth)
        except InputError as e:
            raise InputError(f"sample {n}: {s.depth.name}: {_bare(e)}", where=str(s.depth)) from e
        _shape(n, s.depth, depth, hw, None)
        _finite(n, s.depth, depth)
        depth = np.where(depth > 0, depth, 0.0).astype(np.float32)
        # 3. normals (8-bit PNG, e * 0.5 + 0.5, no gamma)
        enc = _read(n, s.normal)
        _shape(n, s.normal, enc, hw, 3)
        normals = decode_official_normals(2.0 * enc[..., :3] - 1.0)
        self._facing(n, normals)
        # 4. albedo (8-bit PNG, gamma 2.2)
        a = _read(n, s.albedo)
        _shape(n, s.albedo, a, hw, 3)
        out = {"image": image, "depth": depth, "normals": normals,
               "albedo": np.clip(a[..., :3], 0, 1).astype(np.float32) ** GAMMA}
        # 5. material (PNG data, first channel)
        if self.need_material:
            for key, p in (("roughness", s.roughness), ("metallic", s.metallic)):
                v = _first_channel(_read(n, p))
                _shape(n, p, v, hw, None)
                out[key] = np.clip(v, 0, 1).astype(np.float32)
        return {k: np.ascontiguousarray(v, np.float32) for k, v in out.items()}


# ----------------------------------------------------------------------------- InteriorVerse


_IV_SUFFIXES = ("depth", "normal", "albedo", "material")


class InteriorVerseDataset:
    """InteriorVerse renders (Zhu et al., SIGGRAPH Asia 2022): ``root/<scene>/<id>_im.exr``
    with ``<id>_depth.exr`` (millimetres, +inf = no surface), ``<id>_normal.exr`` (unit
    vectors), ``<id>_albedo.exr`` (linear) and ``<id>_material.exr`` (R = roughness,
    G = metallic), all float EXR.

    Args:
        root: dataset root (one folder per scene).
        need_material: also return roughness and metallic (the material EXR is then required).
        exposure: ``"none"`` (default: the official loader uses the EXR radiance as is,
            clipped to [0, 1]) or ``"p95"``.

    Non-finite values are accepted only where the depth says "no surface" (they become 0,
    like the official loader's ``nan_to_num``); anywhere else they raise InputError.
    """

    layout = "interiorverse"

    def __init__(self, root, *, need_material: bool = False, exposure: str = "none"):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"dataset root not found: {self.root}")
        if exposure not in ("p95", "none"):
            raise InputError(f"interiorverse: exposure must be 'p95' or 'none', got {exposure!r}")
        self.need_material, self.exposure = need_material, exposure
        ims = sorted(self.root.glob("*/*_im.exr"))
        if not ims:
            raise InputError(f"interiorverse dataset {self.root}: no <scene>/<id>_im.exr found")
        self.samples = ims
        need = ("depth", "normal", "albedo") + (("material",) if need_material else ())
        missing = [f"sample {self.sample_name(k)}: missing {self._path(k, s).name} "
                   f"(looked for {self._path(k, s)})"
                   for k in range(len(ims)) for s in need if not self._path(k, s).is_file()]
        _raise_missing("interiorverse", self.root, missing)
        self._facing = _BackfacingCheck(self.layout)

    def __len__(self) -> int:
        return len(self.samples)

    def sample_name(self, i: int) -> str:
        p = self.samples[i]
        return f"{p.parent.name}/{p.name[:-len('_im.exr')]}"

    def _path(self, i: int, suffix: str) -> Path:
        p = self.samples[i]
        return p.with_name(p.name[:-len("im.exr")] + f"{suffix}.exr")

    def __getitem__(self, i) -> dict:
        n = self.sample_name(i)
        # 1. depth first: it says which pixels hold a surface
        dp = self._path(i, "depth")
        d = _first_channel(_read(n, dp))
        hw = d.shape[:2]
        with np.errstate(invalid="ignore"):
            surface = (d == d) & (d > 0) & (d < IV_DEPTH_MAX_MM)   # NaN != NaN
        if np.isnan(d).any():
            raise InputError(f"sample {n}: {dp.name} holds NaN depth", where=str(dp))
        depth = np.where(surface, d * IV_DEPTH_SCALE, 0.0).astype(np.float32)

        def load(suffix: str, c: int | None) -> tuple[Path, np.ndarray]:
            p = self._path(i, suffix)
            a = _read(n, p)
            _shape(n, p, a, hw, c)
            a = a[..., :c] if c else a
            _finite(n, p, a, where=surface)
            # finite values are kept as stored, even off-surface (as the official loader)
            return p, np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)

        # 2. image (linear HDR)
        ip = self.samples[i]
        img = _read(n, ip, channels=3)
        _shape(n, ip, img, hw, 3)
        _finite(n, ip, img, where=surface)
        img = np.clip(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0), 0, None)
        if self.exposure == "p95":
            image, _ = expose_p95(img, surface)
        else:
            image = np.clip(img, 0, 1)
        # 3. normals, albedo [, material]
        _, enc = load("normal", 3)
        normals = decode_official_normals(enc)
        self._facing(n, normals)
        _, albedo = load("albedo", 3)
        out = {"image": image, "depth": depth, "normals": normals,
               "albedo": np.clip(albedo, 0, 1)}
        if self.need_material:
            _, mat = load("material", 2)
            out["roughness"] = np.clip(mat[..., 0], 0, 1)
            out["metallic"] = np.clip(mat[..., 1], 0, 1)
        return {k: np.ascontiguousarray(v, np.float32) for k, v in out.items()}
