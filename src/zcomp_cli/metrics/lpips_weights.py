"""The two files LPIPS needs, found, or fetched on first use into zcomp's cache.

LPIPS-Alex (v0.1) is torchvision's AlexNet (``alexnet-owt-7be5be79.pth``, 244 MB) and the
paper's five linear layers (``alex.pth``, 6 kB, shipped in the ``lpips`` package). Neither
can ship with zcomp. As diffusers does for its models, zcomp fetches what is missing on
first use, checks it against the published SHA-256 and keeps it in its cache
(``<cache root>/lpips/``, ``zcomp_cli.cache``):

1. a file the user gives (``--lpips-backbone`` / ``--lpips-weights`` or
   ``$ZCOMP_LPIPS_BACKBONE`` / ``$ZCOMP_LPIPS_WEIGHTS``): used as given, the offline path;
   one that is not the published file is used with a note (its scores are not the
   paper's LPIPS);
2. a copy already on the machine whose hash is the published one: zcomp's cache, torch
   hub's cache (``$TORCH_HOME/hub/checkpoints/``), an installed ``lpips`` package;
3. else a download from the published address (or ``$ZCOMP_LPIPS_MIRROR``, a base URL
   holding both files by their published names), refused unless its SHA-256 is the
   published one, written to the cache atomically; never with ``$ZCOMP_OFFLINE`` set;
4. else ``WeightsError``, naming what was looked at, why the download failed and how to
   give the file.

The hashes: ``alex.pth``'s is that of the copy in the ``lpips`` 0.1.4 wheel (the
file of richzhang/PerceptualSimilarity's ``lpips/weights/v0.1/``); the AlexNet's is the
one Hugging Face lists for copies of the file (its first 8 hex digits are those torch
hub puts in the name, ``7be5be79``, which torch hub itself checks).
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

from zcomp_cli.errors import WeightsError

log = logging.getLogger(__name__)

MIRROR_ENV = "ZCOMP_LPIPS_MIRROR"
OFFLINE_ENV = "ZCOMP_OFFLINE"
# A download may take this long to answer or stall (seconds), and be at most this big:
# the AlexNet is 244 MB; a server sending more is not sending it.
DOWNLOAD_TIMEOUT_S = 60
MAX_DOWNLOAD_BYTES = 512 << 20


@dataclass(frozen=True)
class PublishedFile:
    """One weight file: ``what`` (for messages), ``name`` (its published file name),
    ``url``, ``sha256``, ``size`` (bytes, about; for the message before a download), and
    the flag and environment variable that give it."""

    what: str
    name: str
    url: str
    sha256: str
    size: int
    flag: str
    env: str


BACKBONE = PublishedFile(
    "AlexNet backbone", "alexnet-owt-7be5be79.pth", "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
    "7be5be791159472b1fbf3c69796f7cb30dca7ad8466c2df70058c37116cdee02", 244 << 20,
    "--lpips-backbone", "ZCOMP_LPIPS_BACKBONE")
LINEAR = PublishedFile(
    "linear weights (v0.1 alex.pth)", "alex.pth",
    "https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/master/lpips/weights/v0.1/alex.pth",
    "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0", 6 << 10,
    "--lpips-weights", "ZCOMP_LPIPS_WEIGHTS")


@dataclass
class Resolved:
    """A weight file to load, and a note when it is not the published one."""

    path: Path
    note: str | None = None


def sha256_of(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cached_path(pf: PublishedFile, cache_root=None) -> Path:
    from zcomp_cli.cache import cache_dir

    return cache_dir("lpips", cache_root) / pf.name


def resolve(pf: PublishedFile, given=None, local: list[Path] = (), *, cache_root=None) -> Resolved:
    """The file of ``pf`` to load (module docstring, steps 1-4). ``given``: the flag's
    path (else ``pf.env``); ``local``: copies that may be on the machine, in order."""
    source = pf.flag if given else f"${pf.env}"
    given = given or os.environ.get(pf.env) or None
    if given:
        p = Path(given).expanduser()
        if not p.is_file():
            raise WeightsError(f"LPIPS {pf.what} not found at {p} (given by {source}); give the published file "
                               f"({pf.url}) there, or leave {pf.flag} and ${pf.env} unset to fetch it once")
        digest = sha256_of(p)
        note = None if digest == pf.sha256 else (
            f"{p} is not the published LPIPS {pf.what} (sha256 {digest[:16]}..., published {pf.sha256[:16]}...): "
            "its scores are not the paper's LPIPS")
        return Resolved(p, note)
    cache = cached_path(pf, cache_root)
    looked = []
    for p in [cache, *local]:
        looked.append(str(p))
        if p.is_file() and sha256_of(p) == pf.sha256:
            return Resolved(p)
    why = download(pf, cache)
    if why is None:
        return Resolved(cache)
    raise WeightsError(f"LPIPS {pf.what} ({pf.name}) is not on this machine (looked at {', '.join(looked)}) and "
                       f"{why}; give it with {pf.flag} PATH or ${pf.env} (the published file: {pf.url}, "
                       f"sha256 {pf.sha256})")


def download(pf: PublishedFile, dest: Path) -> str | None:
    """Fetch ``pf`` into ``dest`` (atomically, checked); None on success, else why not
    (in words that follow "and")."""
    if os.environ.get(OFFLINE_ENV, "").strip() not in ("", "0"):
        return f"${OFFLINE_ENV} is set, so it is not downloaded"
    mirror = os.environ.get(MIRROR_ENV, "").strip()
    url = f"{mirror.rstrip('/')}/{pf.name}" if mirror else pf.url
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"zcomp's cache {dest.parent} cannot be written ({exc.strerror or exc})"
    log.info("LPIPS: downloading the %s (%.0f MB, once) from %s into %s", pf.what, pf.size / 2**20, url, dest.parent)
    tmp = dest.with_name(f".{dest.name}.part-{os.getpid()}")
    try:
        digest, n = _fetch(url, tmp)
        if n > MAX_DOWNLOAD_BYTES:
            return f"the download from {url} passed {MAX_DOWNLOAD_BYTES:,} bytes (not the file); nothing was kept"
        if digest != pf.sha256:
            return (f"the file downloaded from {url} is not the published one (sha256 {digest}, published "
                    f"{pf.sha256}); nothing was kept")
        os.replace(tmp, dest)
        return None
    except OSError as exc:  # urllib's errors are OSErrors: refused, unreachable, timed out, HTTP 404
        return f"the download from {url} failed ({_why(exc)})"
    finally:
        tmp.unlink(missing_ok=True)


def _fetch(url: str, tmp: Path) -> tuple[str, int]:
    """Stream ``url`` into ``tmp``: (its sha256, bytes read); stops past
    ``MAX_DOWNLOAD_BYTES``."""
    import urllib.request

    h, n = hashlib.sha256(), 0
    with urllib.request.urlopen(url, timeout=DOWNLOAD_TIMEOUT_S) as r, open(tmp, "wb") as f:
        while chunk := r.read(1 << 20):
            n += len(chunk)
            if n > MAX_DOWNLOAD_BYTES:
                break
            h.update(chunk)
            f.write(chunk)
    return h.hexdigest(), n


def _why(exc: OSError) -> str:
    reason = getattr(exc, "reason", None)
    code = getattr(exc, "code", None)
    if code is not None:
        return f"HTTP {code}"
    return str(reason or exc.strerror or exc)[:200]


__all__ = ["BACKBONE", "LINEAR", "MIRROR_ENV", "OFFLINE_ENV", "PublishedFile", "Resolved", "cached_path",
           "download", "resolve", "sha256_of"]
