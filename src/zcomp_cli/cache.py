"""zcomp's one on-disk cache: where it lives, and one subfolder per kind of entry.

``cache_root()`` is ``--cache-dir`` when a command is given one, else
``$ZCOMP_CACHE_DIR``, else ``~/.cache/zcomp``. Below it:

* ``intrinsics/``: object intrinsics bundles rendered by Blender (``blender.cache``);
* ``estimates/``: per-scene estimated maps (``estimators.cache``);
* ``lights/``: per-scene fitted lights (``light.stage``);
* ``lpips/``: the LPIPS weights, fetched on first use (``metrics.lpips_weights``).

Every command resolves its folders here, so ``render-intrinsics``, ``composite`` and
``estimate`` share entries.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "ZCOMP_CACHE_DIR"
KINDS = ("intrinsics", "estimates", "lights", "lpips")


def cache_root(override: str | os.PathLike | None = None) -> Path:
    """The cache's root folder: ``override``, else ``$ZCOMP_CACHE_DIR``, else
    ``~/.cache/zcomp`` (not created here)."""
    if override is not None:
        return Path(override).expanduser()
    env = os.environ.get(ENV_VAR)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "zcomp"


def cache_dir(kind: str, root: str | os.PathLike | None = None) -> Path:
    """The folder of one kind of entry (``intrinsics``, ``estimates``, ``lights``, ``lpips``) under
    :func:`cache_root` (``root`` overrides the root, as ``--cache-dir`` does)."""
    if kind not in KINDS:
        raise ValueError(f"unknown cache kind {kind!r}; known: {', '.join(KINDS)}")
    return cache_root(root) / kind
