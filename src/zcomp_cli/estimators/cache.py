"""Per-scene estimate cache: one EXR per (image content hash, estimator, settings)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np


def content_key(*parts) -> str:
    """A short sha256 over arrays (bytes, shape, dtype) and JSON-able settings."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(str((a.shape, a.dtype.str)).encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"|")
    return h.hexdigest()[:20]


class EstimateCache:
    """Reads and writes ``<dir>/<map>-<key>.exr``; a ``None`` dir caches nothing."""

    def __init__(self, cache_dir=None):
        self.dir = Path(cache_dir) if cache_dir is not None else None

    def path(self, name: str, key: str) -> Path | None:
        return None if self.dir is None else self.dir / f"{name}-{key}.exr"

    def get(self, name: str, key: str, channels: int) -> np.ndarray | None:
        p = self.path(name, key)
        if p is None or not p.is_file():
            return None
        from zcomp_cli.imageio import read_map

        try:
            return read_map(p, channels=channels).astype(np.float32)
        except Exception:  # a corrupt cache entry is recomputed, not fatal
            return None

    def put(self, name: str, key: str, arr: np.ndarray) -> None:
        p = self.path(name, key)
        if p is None:
            return
        from zcomp_cli.imageio import write_exr

        p.parent.mkdir(parents=True, exist_ok=True)
        write_exr(p, np.asarray(arr, np.float32))  # atomic: readers never see half a file
