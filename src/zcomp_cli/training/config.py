"""`zcomp train` YAML config, validated with errors naming the key."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from zcomp_cli.errors import UsageError

LAYOUTS = ("zcomp", "openrooms", "interiorverse")


@dataclass
class TrainConfig:
    base: str
    data_root: str
    output_dir: str
    layout: str = "zcomp"
    channels: int = 11
    resolution: int = 512
    batch_size: int = 32
    lr: float = 8e-5
    weight_decay: float = 1e-2
    max_steps: int = 10000
    save_every: int = 1000
    grad_clip: float = 1.0
    seed: int = 0
    resume: str | None = None  # checkpoint dir, or "latest"
    device: str = "auto"


def _get(d, key, typ, default=None, required=False):
    if key not in d or d[key] is None:
        if required:
            raise UsageError(f"train config: missing required key {key!r}")
        return default
    v = d[key]
    try:
        return typ(v) if typ is not str else str(v)
    except (TypeError, ValueError):
        raise UsageError(f"train config: key {key!r} must be {typ.__name__}, got {v!r}") from None


def parse_config(d: dict) -> TrainConfig:
    if not isinstance(d, dict):
        raise UsageError("train config: top level must be a mapping")
    known = set(TrainConfig.__dataclass_fields__) | {"dataset"}
    unknown = set(d) - known
    if unknown:
        raise UsageError(f"train config: unknown key(s) {sorted(unknown)}")
    ds = d.get("dataset") or {}
    if not isinstance(ds, dict):
        raise UsageError("train config: key 'dataset' must be a mapping {layout, root}")
    c = TrainConfig(
        base=_get(d, "base", str, required=True),
        data_root=_get(ds, "root", str, required=True) if ds else _get(d, "data_root", str, required=True),
        output_dir=_get(d, "output_dir", str, required=True),
        layout=_get(ds, "layout", str, "zcomp"),
        channels=_get(d, "channels", int, 11), resolution=_get(d, "resolution", int, 512),
        batch_size=_get(d, "batch_size", int, 32), lr=_get(d, "lr", float, 8e-5),
        weight_decay=_get(d, "weight_decay", float, 1e-2),
        max_steps=_get(d, "max_steps", int, 10000), save_every=_get(d, "save_every", int, 1000),
        grad_clip=_get(d, "grad_clip", float, 1.0), seed=_get(d, "seed", int, 0),
        resume=_get(d, "resume", str, None), device=_get(d, "device", str, "auto"))
    if c.layout not in LAYOUTS:
        raise UsageError(f"train config: key 'dataset.layout' must be one of {LAYOUTS}, got {c.layout!r}")
    if c.channels not in (10, 11, 13):
        raise UsageError(f"train config: key 'channels' must be 10, 11 or 13, got {c.channels}")
    for k in ("resolution", "batch_size", "max_steps", "save_every"):
        if getattr(c, k) < 1:
            raise UsageError(f"train config: key {k!r} must be >= 1")
    if c.resolution % 8:
        raise UsageError("train config: key 'resolution' must be a multiple of 8")
    if c.lr <= 0 or c.grad_clip <= 0:
        raise UsageError("train config: keys 'lr' and 'grad_clip' must be > 0")
    return c


def load_config(path) -> TrainConfig:
    import yaml

    p = Path(path)
    if not p.is_file():
        raise UsageError(f"train config not found: {p}")
    try:
        d = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise UsageError(f"train config {p}: invalid YAML: {e}") from e
    return parse_config(d)
