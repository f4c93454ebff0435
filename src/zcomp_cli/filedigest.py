"""A file's content digest, for the caches and the output records (below every layer:
the Blender cache and the pipeline's output guard both read it), and the digest of a
package's sources (the light cache's key, a sweep's frozen copy)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def sha256_file(path: Path) -> str:
    """The SHA-256 of the file's bytes, hex (read in 1 MiB chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def sources_sha256(root: Path, relative_to: Path) -> str:
    """The SHA-256 of the Python sources under ``root`` (every ``.py``, sorted, each by
    its path relative to ``relative_to``, a NUL, and its bytes), hex. A file that cannot
    be read (an editor's lock file, a dangling link) is no source and is left out."""
    h = hashlib.sha256()
    for path in sorted(Path(root).rglob("*.py")):
        try:
            data = path.read_bytes()
        except OSError:
            continue
        h.update(path.relative_to(relative_to).as_posix().encode() + b"\0" + data)
    return h.hexdigest()


__all__ = ["sha256_file", "sources_sha256"]
