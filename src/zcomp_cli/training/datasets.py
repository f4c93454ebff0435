"""Training datasets. Every sample is a dict of linear float32 maps in zcomp conventions:
image (H,W,3 linear), depth (H,W metres), normals (H,W,3 camera/OpenGL), albedo (H,W,3
linear) [, roughness, metallic (H,W)].

Layouts implemented:
- ``zcomp``: ``<root>/<sample>/{image,depth,normals,albedo[,roughness,metallic]}.npy``
  (the arrays zcomp's bundles hold, as .npy).
- ``openrooms`` / ``interiorverse``: ``training/datasets_external.py``; see docs/zerocomp.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from zcomp_cli.errors import InputError, UsageError

REQUIRED = ("image", "depth", "normals", "albedo")
OPTIONAL = ("roughness", "metallic")


class ZcompBundleDataset:
    def __init__(self, root, *, need_material: bool = False):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"dataset root not found: {self.root}")
        self.samples = sorted(p for p in self.root.iterdir() if p.is_dir())
        if not self.samples:
            raise InputError(f"dataset {self.root}: no sample directories")
        self.need_material = need_material

    def __len__(self):
        return len(self.samples)

    def __getitem__(self, i) -> dict:
        d = self.samples[i]
        names = REQUIRED + (OPTIONAL if self.need_material else ())
        out = {}
        for n in names:
            f = d / f"{n}.npy"
            if not f.is_file():
                raise InputError(f"sample {d}: missing {f.name}")
            a = np.load(f).astype(np.float32)
            if not np.isfinite(a).all():
                raise InputError(f"sample {d}: {f.name} holds NaN/Inf")
            out[n] = a
        h, w = out["depth"].shape[:2] if out["depth"].ndim >= 2 else (0, 0)
        for n, a in out.items():
            want = (h, w, 3) if n in ("image", "normals", "albedo") else (h, w)
            if a.shape != want:
                raise InputError(f"sample {d}: {n}.npy has shape {a.shape}, expected {want}")
        return out


def open_dataset(layout: str, root, *, channels: int = 11):
    if layout == "zcomp":
        return ZcompBundleDataset(root, need_material=channels == 13)
    if layout in ("openrooms", "interiorverse"):
        from zcomp_cli.training.datasets_external import InteriorVerseDataset, OpenRoomsDataset

        cls = OpenRoomsDataset if layout == "openrooms" else InteriorVerseDataset
        return cls(root, need_material=channels == 13)
    raise UsageError(f"dataset layout {layout!r} is not known "
                     "(use 'zcomp', 'openrooms' or 'interiorverse')")
