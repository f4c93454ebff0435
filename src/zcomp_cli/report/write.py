"""``write_report``: collect an output folder's rows, link (or thumbnail) its images and
write the page, atomically, inside the folder."""

from __future__ import annotations

import hashlib
import os
import re
import urllib.parse
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.limits import field_text
from zcomp_cli.report.collect import Collected, collect

DEFAULT_NAME = "report.html"
DEFAULT_PAGE_SIZE = 100
# Backgrounds a browser cannot show (EXR, HDR, TIFF) become small PNGs here, in OUT.
THUMBS_DIR = "report_thumbs"
THUMB_SIZE = 320  # longest side, pixels (shown at 160 px: sharp on a high-density screen)
BROWSER_IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".gif", ".webp", ".bmp", ".avif"}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,127}")


def check_name(name: str) -> None:
    """``--name``: a plain file name ending in .html (the page lies in OUT, so its
    relative links hold)."""
    if not _NAME.fullmatch(name or "") or not name.lower().endswith((".html", ".htm")):
        raise UsageError(f"--name {name!r}: expected a file name ending in .html, made of letters, digits, "
                         f"'_', '-' and '.' (the page is written inside OUT)")


def rel_url(path, base) -> str:
    """A URL for ``path`` relative to the folder ``base`` (``..`` when it lies outside),
    percent-encoded; an absolute file URL where there is no relative path (another
    drive)."""
    try:
        rel = os.path.relpath(os.path.abspath(path), os.path.abspath(base))
    except ValueError:
        return Path(os.path.abspath(path)).as_uri()
    # (a name of undecodable bytes: their percent-encoding, as a browser reads the file)
    return urllib.parse.quote(os.fsencode(rel.replace(os.sep, "/")), safe="/")


def write_report(out, *, name: str = DEFAULT_NAME, title: str | None = None,
                 page_size: int = DEFAULT_PAGE_SIZE, manifest=None, eval_file=None,
                 verify: bool = False) -> tuple[Path, Collected]:
    """Write ``OUT/<name>`` for the output folder ``out``; return its path and what it
    shows. Nothing is written outside ``out``."""
    from zcomp_cli import __version__
    from zcomp_cli.imageio import write_text_atomic
    from zcomp_cli.report.html import render_page

    check_name(name)
    if page_size < 1:
        raise UsageError(f"--page-size {page_size}: expected 1 or more")
    out = Path(out)
    col = collect(out, manifest=manifest, eval_file=eval_file, verify=verify)
    if (out / name).is_dir():
        raise UsageError(f"{out / name} is a folder: give another --name")
    backgrounds = background_urls(col, out)
    urls = {"composite": {}, "background": backgrounds}
    for r in col.rows:
        if r["composite"] is not None:
            urls["composite"][r["job"]] = rel_url(r["composite"], out)
    page = render_page(col, title=title or f"zcomp report: {field_text(out.resolve().name)}", page_size=page_size,
                       urls=urls, url_of=lambda p: rel_url(p, out), version=__version__)
    path = out / name
    write_text_atomic(path, page)
    return path, col


def background_urls(col: Collected, out: Path) -> dict[str, str]:
    """Job name -> the URL of its background: a relative link to the photograph when a
    browser can show it, else a thumbnail written in ``OUT/report_thumbs/`` (kept while
    its photograph is unchanged; thumbnails no job uses any more are removed)."""
    by_src: dict[Path, str | None] = {}
    used: set[str] = set()
    jobs = {r["job"] for r in col.rows}
    for r in col.rows:
        src = r["background"]
        if src is None or src in by_src:
            continue
        if src.suffix.lower() in BROWSER_IMAGE_EXTS:
            by_src[src] = rel_url(src, out)
            continue
        if (out / THUMBS_DIR).is_symlink():  # nothing is written outside OUT
            raise UsageError(f"{out / THUMBS_DIR} is a symbolic link: remove it (zcomp report writes "
                             f"background thumbnails there)")
        if THUMBS_DIR in jobs or (out / THUMBS_DIR / "report.json").exists():  # a job took the name
            col.notes.append(f"no thumbnail of {src}: {out / THUMBS_DIR} is a job's folder")
            by_src[src] = None
            continue
        try:
            thumb = _thumbnail(src, out / THUMBS_DIR)
        except Exception as exc:  # noqa: BLE001 - an unreadable photograph: no background shown
            col.notes.append(f"no thumbnail of {src}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
            by_src[src] = None
            continue
        used.add(thumb.name)
        by_src[src] = rel_url(thumb, out)
    if THUMBS_DIR not in jobs and not (out / THUMBS_DIR / "report.json").exists():
        _prune(out / THUMBS_DIR, used)
    return {r["job"]: by_src[r["background"]] for r in col.rows
            if r["background"] is not None and by_src.get(r["background"])}


def _thumbnail(src: Path, folder: Path) -> Path:
    st = src.stat()
    key = hashlib.sha1(f"{os.path.abspath(src)}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:20]
    dst = folder / f"bg-{key}.png"
    if dst.is_file():
        return dst
    import cv2
    import numpy as np

    from zcomp_cli.imageio import read_image, write_png

    img = read_image(src)
    h, w = img.shape[:2]
    s = min(1.0, THUMB_SIZE / max(h, w))
    if s < 1.0:
        img = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    write_png(dst, np.clip(np.nan_to_num(img), 0.0, None))
    return dst


def _prune(folder: Path, used: set[str]) -> None:
    if not folder.is_dir() or folder.is_symlink():
        return
    for p in folder.glob("bg-*.png"):
        if p.name not in used:
            try:
                p.unlink()
            except OSError:
                pass


__all__ = ["DEFAULT_NAME", "DEFAULT_PAGE_SIZE", "THUMBS_DIR", "check_name", "rel_url", "write_report",
           "background_urls"]
