"""Image and map I/O at the edge of the program (DESIGN.md section 3).

* 8/16-bit PNG/JPEG/TIFF are sRGB-encoded colour: decoded with the exact sRGB curve
  (``read_image``) unless read as data (``read_map``, which only rescales to [0, 1]).
* EXR/HDR are linear float.
* Every write is atomic: a temporary file in the same folder, then ``os.replace``, so
  an interrupted run never leaves a half-written output that a resume would trust.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from zcomp_cli.conventions import linear_to_srgb, srgb_to_linear
from zcomp_cli.errors import InputError

FLOAT_EXTS = {".exr", ".hdr"}


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success move it over ``path``.

    The temporary name keeps the extension so that writers that pick the format from
    the name (OpenImageIO, matplotlib) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = suffix if suffix is not None else path.suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600 files; outputs get the usual permissions (umask applied).
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)


def write_json_atomic(path, obj) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating,)):
        return float(o)
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
        raise ValueError(oiio.geterror() or "unreadable image")
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height), int(spec.nchannels)
    finally:
        inp.close()


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
        raise InputError(f"cannot read image: {oiio.geterror() or 'unknown format'}", where=str(path))
    try:
        spec = inp.spec()
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
    finally:
        inp.close()
    if data is None or not isinstance(data, np.ndarray):
        raise InputError(f"cannot decode pixels: {oiio.geterror()}", where=str(path))
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
    data, kind = _read_raw(path)
    img = _to_unit(data, kind)
    if kind != "float":
        img = srgb_to_linear(img)
    return _fit_channels(img, channels, path)


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
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise InputError(f"cannot write EXR: {oiio.geterror()}", where=str(path))
        try:
            if not out.write_image(np.ascontiguousarray(arr)):
                raise InputError(f"cannot write EXR: {out.geterror()}", where=str(path))
        finally:
            out.close()


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
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise InputError(f"cannot write PNG: {oiio.geterror()}", where=str(path))
        try:
            out.write_image(np.ascontiguousarray(pix))
        finally:
            out.close()


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
