"""The papers' own published figures, printed by ``zcomp eval`` beside a run's.

A dataset is known when each reference's folder holds the ``case.json`` that
``zcomp import`` writes. The published rows of a dataset come from ``PUBLISHED`` (bundled)
or from ``--paper-rows FILE`` (YAML or JSON)::

    dataset: zerocomp-labo
    source: "Zhang et al., ZeroComp, WACV 2025, Table 1"
    rows:
      - name: "ZeroComp (OpenRooms, 7 days)"
        region: full                  # or object-crop
        psnr: 0.0                     # any of psnr, ssim, lpips, si-rmse, mae, ...
        lpips: 0.0

No figure is bundled: the paper's text could not be read where this version was built
(docs/reproduce.md, "The paper's figures"), and a number nobody checked is worse than
none. ``PUBLISHED`` holds the citation of each table; its ``rows`` stay empty until
someone transcribes them from the paper and sets ``verified``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from zcomp_cli.errors import UsageError

# Written by `zcomp import` beside each case's reference.
CASE_FILE = "case.json"

PUBLISHED: dict[str, dict] = {
    "zerocomp-labo": {
        "source": "Zhang, Fortier-Chouinard, Garon, Bhattad, Lalonde: ZeroComp: Zero-shot Object Compositing "
                  "from Image Intrinsics via Diffusion, WACV 2025, Table 1 (arXiv:2410.08168)",
        "verified": False,
        "rows": [],
    },
    "spotlight": {
        "source": "Fortier-Chouinard, Zhang, Messier, Garon, Bhattad, Lalonde: SpotLight: Shadow-Guided Object "
                  "Relighting via Diffusion (arXiv:2411.18665)",
        "verified": False,
        "rows": [],
    },
}


def dataset_of_reference(ref) -> str | None:
    """The dataset key of an imported case (``case.json`` beside its reference), else None."""
    try:
        d = json.loads((Path(ref).parent / CASE_FILE).read_text())
    except (OSError, ValueError):
        return None
    v = d.get("dataset") if isinstance(d, dict) else None
    return v if isinstance(v, str) else None


def dataset_of_pairs(pairs) -> str | None:
    """The one dataset every pair's reference belongs to, else None (mixed or unknown)."""
    keys = {dataset_of_reference(p.ref) for p in pairs}
    return keys.pop() if len(keys) == 1 and None not in keys else None


def load_rows(path) -> dict:
    """Read and check a ``--paper-rows`` file; UsageError naming the field."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise UsageError(f"--paper-rows {path}: cannot read: {exc}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list) or not data["rows"]:
        raise UsageError(f"--paper-rows {path}: expected a mapping with a non-empty list 'rows'")
    rows = []
    for i, r in enumerate(data["rows"]):
        where = f"--paper-rows {path}: rows[{i}]"
        if not isinstance(r, dict) or not isinstance(r.get("name"), str):
            raise UsageError(f"{where}: expected a mapping with a 'name'")
        region = r.get("region", "full")
        if region not in ("full", "object-crop"):
            raise UsageError(f"{where}.region: expected full or object-crop, got {region!r}")
        metrics = {}
        for k, v in r.items():
            if k in ("name", "region", "checkpoint"):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UsageError(f"{where}.{k}: expected a finite number, got {v!r}")
            metrics[str(k).lower().replace("_", "-")] = float(v)
        rows.append({"name": r["name"], "region": region, "checkpoint": r.get("checkpoint"), "metrics": metrics})
    src = data.get("source")
    return {"dataset": data.get("dataset"), "source": str(src) if src else str(path), "verified": True,
            "rows": rows}


def rows_for(dataset: str | None, region: str, given: dict | None = None) -> tuple[dict | None, list[dict]]:
    """(the table's entry or None, its rows for ``region``): ``given`` (a loaded
    ``--paper-rows`` file) wins over the bundled ``PUBLISHED``."""
    entry = given if given is not None else PUBLISHED.get(dataset or "")
    if entry is None:
        return None, []
    return entry, [r for r in entry["rows"] if r.get("region", "full") == region]
