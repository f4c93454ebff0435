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

Bundled: the figures of the ZeroComp supplementary material (below), each row with its
source. The paper's own Tab. 1 (every method on the whole image) could not be read where
this version was built (docs/reproduce.md, "The paper's figures"): its rows are not
bundled, since a number nobody checked is worse than none.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from zcomp_cli.errors import UsageError

# Written by `zcomp import` beside each case's reference.
CASE_FILE = "case.json"

# The ZeroComp supplementary material (lvsn.github.io/ZeroComp/supp), transcribed from its
# HTML source (github.com/lvsn/lvsn.github.io, ZeroComp/supp/index.html at e845f2c):
# * Sec. 2 "Additional quantitative results": every method on the object crop (the
#   object's box grown by 25 % on each side, LPIPS on 256 x 256 resizes);
# * Sec. 6 "Ablation study on different predictors": ZeroComp with its default
#   predictors (ZoeDepth, StableNormal, Intrinsic Image Diffusion) on the whole image,
#   the setting of the paper's Tab. 1 ("computed on the whole image").
# The paper's Tab. 1 itself (every method on the whole image) could not be read here.
_SUPP = "ZeroComp supplementary material (https://lvsn.github.io/ZeroComp/supp/index.html)"


def _crop(name: str, family: str, *values: float) -> dict:
    """A row of the supplementary's Sec. 2 table (object crop), columns as ``_CROP_COLUMNS``."""
    return {"name": name, "region": "object-crop", "family": family, "source": f"{_SUPP}, Sec. 2",
            "metrics": dict(zip(_CROP_COLUMNS, values))}


_CROP_COLUMNS = ("psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip")

PUBLISHED: dict[str, dict] = {
    "zerocomp-labo": {
        "source": "Zhang, Fortier-Chouinard, Garon, Bhattad, Lalonde: ZeroComp: Zero-shot Object Compositing "
                  "from Image Intrinsics via Diffusion, WACV 2025 (arXiv:2410.08168), supplementary material "
                  "Sec. 2 (object crop) and Sec. 6 (whole image, default predictors)",
        "verified": True,
        "rows": [
            # Sec. 6: "ZeroComp (Ours)", as the supplementary names its OpenRooms model
            {"name": "ZeroComp (ZoeDepth, StableNormal, IID)", "region": "full", "family": "zero-shot intrinsics",
             "source": f"{_SUPP}, Sec. 6",
             "metrics": {"psnr": 31.7, "rmse": 0.0303, "si-rmse": 0.0295, "ssim": 0.970, "mae": 0.0109}},
            _crop("Gardner et al. 2017", "lighting estimation", 18.4, 0.1421, 0.0959, 0.844, 0.0854, 0.1326, 0.2506),
            _crop("Garon et al. 2019", "lighting estimation", 26.7, 0.0509, 0.0477, 0.938, 0.0307, 0.067, 0.1471),
            _crop("Gardner et al. 2019", "lighting estimation", 24.9, 0.0604, 0.0505, 0.926, 0.0354, 0.0826, 0.1664),
            _crop("Everlight", "lighting estimation", 25.8, 0.0578, 0.054, 0.924, 0.0355, 0.0692, 0.1563),
            _crop("StyleLight", "lighting estimation", 22.1, 0.0825, 0.0685, 0.896, 0.0481, 0.101, 0.1904),
            _crop("Weber et al. 2022", "lighting estimation", 22.1, 0.0823, 0.0656, 0.907, 0.0493, 0.0938, 0.2035),
            _crop("EMLight", "lighting estimation", 25.3, 0.0594, 0.0564, 0.918, 0.0359, 0.0786, 0.16),
            _crop("AnyDoor", "image-based", 17.1, 0.1307, 0.1236, 0.639, 0.0817, 0.2739, 0.3058),
            _crop("ControlCom", "image-based", 18.7, 0.1076, 0.0913, 0.704, 0.0686, 0.1992, 0.2903),
            _crop("Careaga et al. 2023", "image-based", 19.1, 0.1087, 0.0832, 0.852, 0.0657, 0.138, 0.2476),
            _crop("ARShadowGAN", "image-based", 21.5, 0.0866, 0.0754, 0.83, 0.0526, 0.1425, 0.2164),
            _crop("ZeroComp OpenRooms", "zero-shot intrinsics", 24.4, 0.0588, 0.0544, 0.87, 0.0356, 0.0961, 0.1691),
            _crop("ZeroComp InteriorVerse", "zero-shot intrinsics", 25.7, 0.0504, 0.0473, 0.885, 0.03, 0.0872, 0.1504),
        ],
    },
    "spotlight": {
        "source": "Fortier-Chouinard, Zhang, Messier, Garon, Bhattad, Lalonde: SpotLight: Shadow-Guided Object "
                  "Relighting via Diffusion (arXiv:2411.18665)",
        "verified": False,
        "rows": [],
    },
}


# The precision the supplementary's tables print each metric with.
_DECIMALS = {"psnr": 1, "ssim": 3}


def format_value(metric: str, value: float) -> str:
    """A published figure as the tables print it (PSNR 24.4, SSIM 0.870, others 0.0670)."""
    return f"{value:.{_DECIMALS.get(metric, 4)}f}"


def _case_dataset(ref) -> tuple[str | None, str | None]:
    """(the dataset key, None) of an imported case; (None, None) when no ``case.json``
    is beside the reference; (None, why) when one is there but cannot be read."""
    path = Path(ref).parent / CASE_FILE
    if not path.exists():
        return None, None
    try:
        d = json.loads(path.read_text())
    except RecursionError:
        return None, f"{path}: JSON nested too deep"
    except (OSError, ValueError) as exc:
        return None, f"{path}: {type(exc).__name__}: {exc}"[:300]
    v = d.get("dataset") if isinstance(d, dict) else None
    return (v, None) if isinstance(v, str) else (None, f"{path}: no 'dataset' text")


def dataset_of_pairs(pairs) -> tuple[str | None, list[str]]:
    """The one dataset the pairs' references belong to, else None; and warnings.

    A ``case.json`` that cannot be read does not decide alone: when every readable one
    names the same dataset, that is the dataset (the broken files are named in the
    warnings: one broken file switched every case to the zcomp protocol, silently).
    References of several datasets, or imported cases beside others, give None with a
    warning saying so."""
    keys: dict[str, int] = {}
    broken: list[str] = []
    plain = 0
    for p in pairs:
        key, why = _case_dataset(p.ref)
        if why:
            broken.append(why)
        elif key is None:
            plain += 1
        else:
            keys[key] = keys.get(key, 0) + 1
    notes = []
    if broken:
        notes.append(f"{len(broken)} case.json file{'s' * (len(broken) != 1)} could not be read (the protocol "
                     f"follows the others): " + "; ".join(broken[:3]) + (" ..." if len(broken) > 3 else ""))
    if len(keys) == 1 and not plain:
        return next(iter(keys)), notes
    if keys:
        parts = [f"{n} {k} case{'s' * (n != 1)}" for k, n in sorted(keys.items())]
        if plain:
            parts.append(f"{plain} reference{'s' * (plain != 1)} not from `zcomp import`")
        notes.append(f"the references mix {', '.join(parts)}: no one dataset's protocol applies (the zcomp "
                     "protocol unless --protocol is given; score each dataset apart to compare with a paper)")
    return None, notes


# A --paper-rows file is a paper's table: these bound it (a judgement, far above any
# published table: ZeroComp's has 12 rows of 6 metrics).
MAX_PAPER_ROWS = 1000
MAX_PAPER_ROW_KEYS = 64
MAX_PAPER_TEXT = 500


def load_rows(path) -> dict:
    """Read and check a ``--paper-rows`` file; UsageError naming the field."""
    from zcomp_cli.errors import ManifestError
    from zcomp_cli.yamlloc import load_yaml

    path = Path(path)
    try:
        # the manifest's bounded loader: size, nesting and alias expansion limited (a
        # 528-byte alias bomb took 4.3 GB and wrote a 1.4 GB eval.json)
        data = load_yaml(path)
    except ManifestError as exc:
        raise UsageError(f"--paper-rows: {exc}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list) or not data["rows"]:
        raise UsageError(f"--paper-rows {path}: expected a mapping with a non-empty list 'rows'")
    if len(data["rows"]) > MAX_PAPER_ROWS:
        raise UsageError(f"--paper-rows {path}: {len(data['rows'])} rows; a paper's table has at most "
                         f"{MAX_PAPER_ROWS}")
    for key in ("dataset", "source"):
        v = data.get(key)
        if v is not None and (not isinstance(v, str) or len(v) > MAX_PAPER_TEXT):
            raise UsageError(f"--paper-rows {path}: {key}: expected text of at most {MAX_PAPER_TEXT} characters")
    rows = []
    for i, r in enumerate(data["rows"]):
        where = f"--paper-rows {path}: rows[{i}]"
        if not isinstance(r, dict) or not isinstance(r.get("name"), str):
            raise UsageError(f"{where}: expected a mapping with a 'name'")
        if len(r["name"]) > MAX_PAPER_TEXT or len(r) > MAX_PAPER_ROW_KEYS:
            raise UsageError(f"{where}: a name of at most {MAX_PAPER_TEXT} characters and at most "
                             f"{MAX_PAPER_ROW_KEYS} keys")
        if r.get("checkpoint") is not None and (not isinstance(r["checkpoint"], str)
                                                or len(r["checkpoint"]) > MAX_PAPER_TEXT):
            raise UsageError(f"{where}.checkpoint: expected text of at most {MAX_PAPER_TEXT} characters")
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
