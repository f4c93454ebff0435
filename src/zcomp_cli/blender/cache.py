"""On-disk cache of object intrinsics bundles, in ``zcomp_cli.cache.cache_dir("intrinsics")``.

Key: sha256 of (mesh content hash, pose, K, resolution, render settings, script
version). An entry is a bundle folder ``<cache>/<key[:2]>/<key>/``; it is complete only
when its ``meta.json`` exists (written last), so entries left by a crash are ignored and
overwritten. Entries are completed in a scratch folder of their writer
(``<cache>/.work-<pid>-*``) and renamed into place in one step; runs sharing a cache
never delete each other's entries (``store``).

Each entry records the sha256 of its files (``cache-hashes.json``); a lookup verifies
them, so an entry edited or damaged after it was made is dropped and rendered again
rather than served. Bundles leave the cache as copies, never hard links: editing a
delivered file cannot reach back into the cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from pathlib import Path

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.imageio import dumps_strict
from zcomp_cli.safe_read import read_json_file


def _canon(x):
    """JSON-stable form: floats rounded to 1e-9 absolute and 12 significant digits, -0.0
    made 0.0 (so that float noise such as 0.1 + 0.2 vs 0.3 does not change a key)."""
    if isinstance(x, float):
        return float(f"{round(x, 9):.12g}") + 0.0
    if isinstance(x, dict):
        return {str(k): _canon(v) for k, v in sorted(x.items())}
    if isinstance(x, (list, tuple)):
        return [_canon(v) for v in x]
    if hasattr(x, "tolist"):
        return _canon(x.tolist())
    return x


def cache_key(*, mesh_hash: str, pose: dict, K, resolution, settings: dict, version: str) -> str:
    """sha256 hex of everything a render depends on."""
    payload = {"mesh": mesh_hash, "pose": pose, "K": K, "resolution": list(resolution),
               "settings": settings, "version": version}
    blob = json.dumps(_canon(payload), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def entry_dir(cache_dir, key: str) -> Path:
    return Path(cache_dir) / key[:2] / key


HASHES = "cache-hashes.json"


def _file_hashes(folder: Path) -> dict[str, str]:
    from zcomp_cli.filedigest import sha256_file

    return {p.name: sha256_file(p) for p in sorted(Path(folder).iterdir()) if p.is_file() and p.name != HASHES}


def lookup(cache_dir, key: str) -> Path | None:
    """The complete, intact cache entry for ``key``, or None. An entry whose files do
    not match their recorded hashes (or that has none) is moved aside and removed."""
    d = entry_dir(cache_dir, key)
    if not _intact(d):
        if d.exists():
            _discard(cache_dir, d)
        return None
    return d


def _intact(d: Path) -> bool:
    if not ObjectBundle.is_complete(d):
        return False
    try:
        recorded = read_json_file(d / HASHES)
        return isinstance(recorded, dict) and recorded == _file_hashes(d)
    except (OSError, ValueError):
        return False


def _scratch(cache_dir, what: str) -> Path:
    """A fresh name for a scratch folder of this process in the cache (``.work-<pid>-``:
    a later run's sweep removes it if this process dies)."""
    return Path(cache_dir) / f".work-{os.getpid()}-{what}-{uuid.uuid4().hex[:12]}"


def _discard(cache_dir, d: Path) -> None:
    """Remove entry ``d`` without ever exposing half of it: rename it away first (a
    reader copying it from its old name keeps a whole entry or finds none)."""
    trash = _scratch(cache_dir, "trash")
    try:
        os.rename(d, trash)
    except OSError:
        return  # gone already, or another run moved it: not ours to remove
    shutil.rmtree(trash, ignore_errors=True)


def copy_bundle(src, dst, meta_update: dict | None = None) -> None:
    """Copy a bundle folder's files into ``dst`` (real copies, not links), meta.json
    last so a reader never sees a complete-looking partial copy. Stale optional maps
    already in ``dst`` are removed. ``meta_update``: keys whose values the copy's
    meta.json takes instead of the source's (a cached bundle's mesh path: the request's
    own file)."""
    src, dst = Path(src), Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    stale_meta = dst / "meta.json"
    if stale_meta.exists():
        stale_meta.unlink()
    names = {p.name for p in src.iterdir() if p.is_file() and p.name != HASHES}
    for name in ("roughness.exr", "metallic.exr"):
        if name not in names and (dst / name).exists():
            (dst / name).unlink()
    for name in sorted(names - {"meta.json"}) + (["meta.json"] if "meta.json" in names else []):
        target = dst / name
        tmp = dst / f".{name}.tmp"
        if tmp.exists():
            tmp.unlink()
        if name == "meta.json" and meta_update:  # (as ObjectBundle.save writes it)
            tmp.write_text(dumps_strict({**read_json_file(src / name), **meta_update}, indent=2) + "\n")
        else:
            shutil.copy2(src / name, tmp)  # a copy: an edited output must not poison the cache
        os.replace(tmp, target)


def store(cache_dir, key: str, bundle_folder) -> Path:
    """Move a finished bundle folder into the cache under ``key``; returns the entry.

    Race-free between runs sharing a cache: the entry is completed (``cache-hashes.json``
    written) under a name of its own, then renamed into place in one step. If an intact
    entry is there already (another run stored the same render first), it is kept and
    ours dropped; a damaged one is moved aside (renamed, then removed) before ours goes
    in. No run ever deletes an entry another run is writing: nobody writes at the
    entry's own name."""
    from zcomp_cli.imageio import write_json_atomic

    final = entry_dir(cache_dir, key)
    final.parent.mkdir(parents=True, exist_ok=True)
    src = Path(bundle_folder)
    staged = _scratch(cache_dir, "store")
    try:
        os.rename(src, staged)
    except OSError:  # another filesystem (or a folder we may not move): copy instead
        copy_bundle(src, staged)
    write_json_atomic(staged / HASHES, _file_hashes(staged))
    try:
        for _ in range(10):
            try:
                os.rename(staged, final)
                return final
            except OSError:  # a non-empty folder is there: another run's entry
                if _intact(final):
                    return final
                _discard(cache_dir, final)
        raise OSError(f"cannot store cache entry {final}: it keeps changing")
    finally:
        if staged.exists():
            shutil.rmtree(staged, ignore_errors=True)
