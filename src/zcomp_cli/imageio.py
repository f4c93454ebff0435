"""Image and map I/O at the edge of the program (DESIGN.md section 3).

* 8/16-bit PNG/JPEG/TIFF are sRGB-encoded colour: decoded with the exact sRGB curve
  (``read_image``) unless read as data (``read_map``, which only rescales to [0, 1]).
* EXR/HDR are linear float.
* Every write is atomic: a temporary file in the same folder, then ``os.replace``, so
  an interrupted run never leaves a half-written output that a resume would trust.
  Write and close errors of the image library (a full disk) raise ``OutputError``
  before the rename, so a truncated file is never installed.
* Every JSON file is strict JSON: non-finite floats are written as ``null`` and the
  document says where (``json_notes``).
* Images larger than the pixel budget (``limits.max_pixels``) are refused from their
  header, before any pixel is allocated.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from zcomp_cli.conventions import linear_to_srgb, srgb_to_linear
from zcomp_cli.errors import InputError, OutputError
from zcomp_cli.limits import MAX_PIXELS_ENV, max_pixels, pixel_budget_problem

FLOAT_EXTS = {".exr", ".hdr"}


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success move it over ``path``.

    The temporary name keeps the extension so that writers that pick the format from
    the name (OpenImageIO, matplotlib) still work, and names the writing process
    (``.<stem>.<pid>-<random>.tmp<ext>``) so that a folder several runs write into can
    tell a killed writer's litter from a live one's (``outguard.clean_dead_writers``).
    """
    from zcomp_cli.interrupts import deferred, made_whole

    path = Path(path)
    suffix = suffix if suffix is not None else path.suffix

    def make():
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, made = tempfile.mkstemp(prefix=f".{path.stem}.{os.getpid()}-", suffix=f".tmp{suffix}", dir=path.parent)
        os.close(fd)
        return made

    try:  # an interrupt waits until the temporary is ours to remove
        tmp = made_whole(make, _unlink_quietly)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror or exc}", where=str(path)) from exc
    try:
        yield Path(tmp)
        if os.path.getsize(tmp) == 0:
            raise OutputError("the writer produced an empty file (disk full?)", where=str(path))
        with deferred():  # installed, or removed: never left half way
            # mkstemp creates 0600 files; outputs get the usual permissions (umask applied).
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, path)
    except OSError as exc:
        _unlink_quietly(tmp)
        raise OutputError(f"cannot write: {exc.strerror or exc}", where=str(path)) from exc
    except BaseException:
        _unlink_quietly(tmp)
        raise


def _unlink_quietly(path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path, text: str) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())


def strict_json(obj) -> tuple[object, list[str]]:
    """A copy of ``obj`` that strict JSON parsers accept: NaN and +-Inf become None.
    Returns (copy, the dotted paths of the replaced values)."""
    replaced: list[str] = []

    def walk(o, path):
        if isinstance(o, dict):
            return {k: walk(v, f"{path}.{k}" if path else str(k)) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [walk(v, f"{path}[{i}]") for i, v in enumerate(o)]
        if isinstance(o, np.ndarray):
            return walk(o.tolist(), path)
        if isinstance(o, (float, np.floating)) and not np.isfinite(o):
            replaced.append(path or "(value)")
            return None
        return o

    return walk(obj, ""), replaced


def dumps_strict(obj, **kw) -> str:
    """``json.dumps`` that never writes NaN/Infinity: they become null, and a dict
    document gets a ``json_notes`` entry naming them."""
    clean, replaced = strict_json(obj)
    if replaced and isinstance(clean, dict):
        shown = ", ".join(replaced[:20]) + (f" and {len(replaced) - 20} more" if len(replaced) > 20 else "")
        clean["json_notes"] = [f"non-finite values (NaN or infinity) written as null: {shown}"]
    return json.dumps(clean, allow_nan=False, default=_json_default, **kw)


def write_json_atomic(path, obj) -> None:
    write_text_atomic(path, dumps_strict(obj, indent=2, sort_keys=False) + "\n")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return strict_json(o.tolist())[0]
    if isinstance(o, (np.floating,)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _oiio():
    import OpenImageIO as oiio  # heavy-ish; imported at first use

    return oiio


def image_header(path) -> tuple[int, int, int]:
    """(width, height, channels) of an image file, reading only its header.
    Raises ValueError when the file cannot be read as an image."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        why = _first_line(oiio.geterror()) or "unreadable image (unknown format)"
        raise ValueError(why + _misnamed(path))
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height), int(spec.nchannels)
    finally:
        inp.close()


def _first_line(text: str | None) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[0][:300] if lines else ""


def verify_image(path) -> tuple[int, int, int]:
    """Like ``image_header``, and also detect truncated files cheaply: a PNG must end
    with its IEND chunk, a JPEG with its end-of-image marker; other formats (EXR,
    TIFF...) must decode their last scanline (EXR reads it from the offset table,
    without the rest of the image). Raises ValueError with the reason."""
    w, h, c = image_header(path)
    if w <= 0 or h <= 0:
        raise ValueError(f"empty image ({w}x{h})")
    real = sniff_format(path)  # the content decides, not the name (a JPEG named .png)
    if real in ("PNG", "JPEG"):
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 64))
            tail = f.read()
        alias = _misnamed(path)
        if real == "PNG" and b"IEND" not in tail[-12:]:
            raise ValueError(f"truncated PNG{alias} (no IEND chunk at the end of the file)")
        if real == "JPEG" and b"\xff\xd9" not in tail:
            raise ValueError(f"truncated JPEG{alias} (no end-of-image marker)")
        return w, h, c
    if pixel_budget_problem(w, 1) is not None:
        return w, h, c  # a single row over budget: the reader will refuse it anyway
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(_first_line(oiio.geterror()) or "unreadable image")
    try:
        spec = inp.spec()
        if spec.tile_width:
            # Tiled files: the last row of tiles (the end of the file in the usual order).
            y0 = ((h - 1) // spec.tile_height) * spec.tile_height
            ok = inp.read_tiles(0, 0, 0, spec.width, y0, h, 0, max(1, spec.depth), 0,
                                spec.nchannels, oiio.FLOAT) is not None
        else:
            ok = inp.read_scanlines(0, 0, h - 1, h, 0, 0, spec.nchannels, oiio.FLOAT) is not None
        if not ok:
            raise ValueError(f"truncated or corrupt: {_first_line(inp.geterror()) or 'cannot decode pixels'}")
    finally:
        inp.close()
    return w, h, c


_MAGIC = ((b"\x89PNG\r\n\x1a\n", "PNG"), (b"\xff\xd8\xff", "JPEG"), (b"v/1\x01", "EXR"),
          (b"#?RADIANCE", "HDR"), (b"#?RGBE", "HDR"), (b"II*\0", "TIFF"), (b"MM\0*", "TIFF"))


_NAMED = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".exr": "EXR", ".hdr": "HDR", ".tif": "TIFF",
          ".tiff": "TIFF"}


def _misnamed(path) -> str:
    """' (a JPEG file named .png)' when the content is another format than the name
    says, else ''."""
    real, named = sniff_format(path), _NAMED.get(Path(path).suffix.lower())
    return f" (a {real} file named {Path(path).suffix})" if real and named and real != named else ""


def sniff_format(path) -> str | None:
    """The format an image file's first bytes say it is (PNG, JPEG, EXR, HDR, TIFF),
    whatever its name; None when unknown."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    return next((name for magic, name in _MAGIC if head.startswith(magic)), None)


def _read_raw(path) -> tuple[np.ndarray, str]:
    """Read pixels as stored: float32 for float formats, native ints otherwise.
    Returns (H x W x C array, format name)."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", where=str(path))
    if path.is_dir():
        raise InputError("is a directory, expected an image file", where=str(path))
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"cannot read image: {_first_line(oiio.geterror()) or 'unknown format'}", where=str(path))
    try:
        spec = inp.spec()
        budget = pixel_budget_problem(spec.width, spec.height)
        if budget:
            raise InputError(f"the image is {budget}", where=str(path))
        fmt = spec.format.basetype
        if fmt in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE):
            data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
            kind = "float"
        elif fmt in (oiio.UINT16, oiio.INT16):
            data = inp.read_image(0, 0, 0, spec.nchannels, oiio.UINT16)
            kind = "uint16"
        else:
            data = inp.read_image(0, 0, 0, spec.nchannels, oiio.UINT8)
            kind = "uint8"
        if data is None or not isinstance(data, np.ndarray):
            why = _first_line(inp.geterror()) or _first_line(oiio.geterror()) or "truncated or corrupt file"
            raise InputError(f"cannot decode pixels: {why}", where=str(path))
    finally:
        inp.close()
    if data.ndim == 2:
        data = data[..., None]
    return data, kind


def _to_unit(data: np.ndarray, kind: str) -> np.ndarray:
    if kind == "uint8":
        return data.astype(np.float32) / 255.0
    if kind == "uint16":
        return data.astype(np.float32) / 65535.0
    return data.astype(np.float32)


def read_image(path, *, channels: int = 3) -> np.ndarray:
    """Read a colour image as **linear** float32 H x W x ``channels``.

    8/16-bit files are decoded from sRGB; float files (EXR/HDR) are taken as linear.
    Grey inputs are repeated to 3 channels; an alpha channel is dropped.
    """
    return read_image_hdr(path, channels=channels)[0]


def read_image_hdr(path, *, channels: int = 3) -> tuple[np.ndarray, bool]:
    """``read_image`` and whether the file holds float pixels (HDR: an EXR, a float TIFF;
    decided by the pixel type, not the name)."""
    data, kind = _read_raw(path)
    img = _to_unit(data, kind)
    if kind != "float":
        img = srgb_to_linear(img)
    return _fit_channels(img, channels, path), kind == "float"


def read_alpha_or_grey(path) -> np.ndarray:
    """Read a mask image as H x W float32 in [0, 1]: the alpha channel if there is one,
    else the grey (first) channel. No sRGB decoding (a mask is data)."""
    data, kind = _read_raw(path)
    img = _to_unit(data, kind)
    c = img.shape[-1]
    out = img[..., 3] if c == 4 else (img[..., 1] if c == 2 else img[..., 0])
    return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0).astype(np.float32)


def read_map(path, *, channels: int | None = None) -> np.ndarray:
    """Read a data map (depth, normals, albedo EXR...) without colour decoding.

    Returns float32 H x W for 1 channel, H x W x C otherwise. With ``channels`` the
    channel count is checked (an RGBA/RGB file is accepted for 1 channel: first channel).
    """
    data, kind = _read_raw(path)
    img = _to_unit(data, kind)
    if channels is not None:
        img = _fit_channels(img, channels, path)
    if img.shape[-1] == 1:
        img = img[..., 0]
    return img


def _fit_channels(img: np.ndarray, channels: int, path) -> np.ndarray:
    c = img.shape[-1]
    if c == channels:
        return img
    if channels == 3 and c in (1, 2):
        return np.repeat(img[..., :1], 3, axis=-1)
    if channels == 3 and c >= 4:
        return img[..., :3]
    if channels == 1 and c >= 1:
        return img[..., :1]
    raise InputError(f"expected {channels} channels, found {c}", where=str(path))


def write_exr(path, data, *, channel_names: list[str] | None = None, half: bool = False) -> None:
    """Write a float map to OpenEXR atomically (float32 unless ``half``).

    ``data`` is H x W or H x W x C. Default channel names: Y (1), RGB (3), RGBA (4).
    """
    oiio = _oiio()
    arr = np.asarray(data, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    h, w, c = arr.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    if channel_names is None:
        channel_names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(
            c, [f"C{i}" for i in range(c)]
        )
    spec.channelnames = tuple(channel_names)
    spec.attribute("compression", "zip")
    # No write time in the header (OpenEXR's capDate): the same image gives the same
    # bytes, so a re-run, a shard or a Ray worker reproduces outputs byte for byte.
    spec.attribute("DateTime", "")
    with atomic_path(path) as tmp:
        _write_checked(oiio, tmp, spec, np.ascontiguousarray(arr), path, "EXR")


def to_uint8_srgb(img_lin) -> np.ndarray:
    """Linear float image -> sRGB uint8 (clipped; NaN -> 0)."""
    return np.round(linear_to_srgb(img_lin) * 255.0).astype(np.uint8)


def write_png(path, img, *, srgb_encode: bool = True, bits: int = 8) -> None:
    """Write an image to PNG atomically.

    Args:
        img: H x W or H x W x C float. Linear colour when ``srgb_encode`` (encoded with
            the sRGB curve), else data in [0, 1] written as is.
        bits: 8 or 16.
    """
    oiio = _oiio()
    arr = np.asarray(img, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    arr = linear_to_srgb(arr) if srgb_encode else np.clip(np.nan_to_num(arr), 0.0, 1.0)
    if bits == 8:
        pix, fmt = np.round(arr * 255.0).astype(np.uint8), oiio.UINT8
    elif bits == 16:
        pix, fmt = np.round(arr * 65535.0).astype(np.uint16), oiio.UINT16
    else:
        raise ValueError("bits must be 8 or 16")
    h, w, c = pix.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    with atomic_path(path) as tmp:
        _write_checked(oiio, tmp, spec, np.ascontiguousarray(pix), path, "PNG")


def _write_checked(oiio, tmp, spec, pixels, path, what: str) -> None:
    """Open, write and close an image, checking each step: the image library reports a
    full disk through its return values, not exceptions."""
    out = oiio.ImageOutput.create(str(tmp))
    if out is None or not out.open(str(tmp), spec):
        why = (out.geterror() if out is not None else "") or oiio.geterror()
        raise OutputError(f"cannot write {what}: {_first_line(why) or 'cannot open the file'}", where=str(path))
    ok = out.write_image(pixels)
    why = "" if ok else out.geterror()
    closed = out.close()
    if not ok or not closed:
        why = why or out.geterror() or oiio.geterror()
        raise OutputError(f"cannot write {what}: {_first_line(why) or 'write failed (disk full?)'}",
                          where=str(path))
    with open(tmp, "rb+") as f:  # on disk before the rename makes it an output
        os.fsync(f.fileno())
    # libpng reports a failed write (EFBIG, ENOSPC) to nobody: read the end back.
    try:
        verify_image(tmp)
    except ValueError as exc:
        raise OutputError(f"cannot write {what}: the written file is incomplete ({exc}; disk full?)",
                          where=str(path)) from exc


def write_image(path, img_lin) -> None:
    """Write a linear colour image, choosing the encoding from the extension
    (.exr: linear float; .png/.jpg: sRGB 8-bit)."""
    ext = Path(path).suffix.lower()
    if ext in FLOAT_EXTS:
        write_exr(path, img_lin)
    elif ext == ".png":
        write_png(path, img_lin)
    else:
        raise InputError(f"unsupported output format {ext!r}", where=str(path))


# The pixel budget (``limits.max_pixels``) is for images of up to this many channels
# (RGBA); an EXR's channels beyond count against it.
EXR_BUDGET_CHANNELS = 4


def read_exr_channels(path) -> dict[str, np.ndarray]:
    """Every channel of an OpenEXR file by its full name (``"albedo.R"``, ``"depth.A"``),
    each an H x W float32 array. A multi-part file's parts are read in turn; a channel
    of a named part without a layer prefix is named ``<part>.<channel>``.

    Raises InputError (naming the file) when it is missing, not an EXR, over the pixel
    budget, truncated, or when two channels share a name.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", where=str(path))
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"cannot read EXR: {_first_line(oiio.geterror()) or 'unknown format'}", where=str(path))
    out: dict[str, np.ndarray] = {}
    try:
        if inp.format_name() != "openexr":
            raise InputError(f"not an OpenEXR file ({inp.format_name()})", where=str(path))
        sub = 0
        values = 0
        while True:
            spec = inp.spec()
            budget = pixel_budget_problem(spec.width, spec.height)
            if budget:
                raise InputError(f"the image is {budget}", where=str(path))
            # the budget is for RGBA pixels: a file's channels, over all its parts,
            # count too (a 619 KB EXR of 301 channels took 2.4 GB)
            values += int(spec.width) * int(spec.height) * int(spec.nchannels)
            if values > EXR_BUDGET_CHANNELS * max_pixels():
                raise InputError(f"{spec.nchannels} channels of {spec.width}x{spec.height} (over all parts: "
                                 f"{values:,} values) exceed the pixel budget of {max_pixels():,} pixels x "
                                 f"{EXR_BUDGET_CHANNELS} channels (set ${MAX_PIXELS_ENV} to raise it)",
                                 where=str(path))
            data = inp.read_image(sub, 0, 0, spec.nchannels, oiio.FLOAT)
            if data is None or not isinstance(data, np.ndarray):
                why = _first_line(inp.geterror()) or "truncated or corrupt file"
                raise InputError(f"cannot decode pixels: {why}", where=str(path))
            data = data.reshape(spec.height, spec.width, spec.nchannels)
            part = spec.getattribute("name") or ""
            for i, ch in enumerate(spec.channelnames):
                name = f"{part}.{ch}" if part and "." not in ch else ch
                if name in out:
                    raise InputError(f"two channels are named {name!r}", where=str(path))
                if out and next(iter(out.values())).shape != data.shape[:2]:
                    raise InputError("the parts of the file differ in size", where=str(path))
                out[name] = np.ascontiguousarray(data[..., i], dtype=np.float32)
            sub += 1
            if not inp.seek_subimage(sub, 0):
                break
    finally:
        inp.close()
    return out
