"""Pair prediction and reference images, score them, write eval.csv / eval.json.

Two layouts:
* two folders, images matched by relative path (extension ignored, so ``a.exr`` in PRED
  pairs with ``a.png`` in REF);
* a ``zcomp composite`` output folder (one sub-folder per job with ``composite.exr`` /
  ``composite.png`` and ``report.json``): the reference is ``report.json["reference"]``,
  or, with ``refs``, the image in ``refs`` whose relative path stem is the job name.

Colour space: pixel metrics (psnr, rmse, si-rmse, ssim, mae) on sRGB-encoded [0, 1]
images unless ``linear``; LPIPS always on sRGB; FLIP in LDR mode on sRGB, in HDR mode on
linear values when both files are float (EXR/HDR).
"""

from __future__ import annotations

import csv
import io
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.errors import InputError, UsageError
from zcomp_cli.safe_read import read_json_file

log = logging.getLogger(__name__)

ALL_METRICS = ("psnr", "rmse", "si-rmse", "ssim", "mae", "lpips", "flip", "shadow-iou", "shadow-darkness")
# Metrics that compare each image with the background it was composited into.
SHADOW_METRICS = ("shadow-iou", "shadow-darkness")
IMAGE_EXTS = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".exr", ".hdr"}
FLOAT_EXTS = {".exr", ".hdr"}
# Whether a larger value is better, for the table's header.
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "shadow-iou": True}
# Smallest image side each metric can score (SSIM's 7x7 window, FLIP's filters); a
# smaller image gets no value for that metric instead of aborting the whole evaluation.
MIN_SIZE = {"ssim": 7, "flip": 2}


def parse_metrics(text: str) -> list[str]:
    """'psnr,lpips' or 'all' -> ordered unique metric names. UsageError on unknown ones."""
    names = [t.strip().lower().replace("_", "-") for t in text.split(",") if t.strip()]
    if not names:
        raise UsageError("no metric given")
    if "all" in names:
        return list(ALL_METRICS)
    bad = [n for n in names if n not in ALL_METRICS]
    if bad:
        raise UsageError(f"unknown metric(s) {', '.join(bad)}; choose from {', '.join(ALL_METRICS)} or all")
    return list(dict.fromkeys(names))


@dataclass
class Pair:
    """One scored item: a prediction, its reference and an optional mask file."""

    name: str
    pred: Path
    ref: Path
    mask: Path | None = None
    background: Path | None = None   # the photograph composited into (shadow metrics)
    object_mask: Path | None = None  # where the object is (kept out of the shadow metrics)


@dataclass
class EvalResult:
    """Per-image values, their means, and the metrics that could not run (and why)."""

    metrics: list[str]
    pairs: list[Pair]
    values: list[dict[str, float]]
    mean: dict[str, float]
    unavailable: dict[str, str] = field(default_factory=dict)
    linear: bool = False
    # Items not scored (a job without a reference...): name -> why.
    unscored: dict[str, str] = field(default_factory=dict)
    # Metric -> why some images have no value (NaN in ``values``, left out of the mean).
    partial: dict[str, str] = field(default_factory=dict)
    # The protocol (metrics/protocol.py): name, encoding, region; the dataset and the
    # paper's rows when known. Empty for the plain zcomp protocol on the whole image.
    protocol: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "metrics": self.metrics,
            "colour_space": "linear" if self.linear else "srgb",
            "images": [
                {"name": p.name, "pred": str(p.pred), "ref": str(p.ref),
                 "mask": str(p.mask) if p.mask else None,
                 **{k: _json_num(v) for k, v in vals.items()}}
                for p, vals in zip(self.pairs, self.values)
            ],
            "mean": {k: _json_num(v) for k, v in self.mean.items()},
            "unavailable": dict(self.unavailable),
            "unscored": dict(self.unscored),
            "partial": dict(self.partial),
            **({"protocol": self.protocol} if self.protocol else {}),
        }

    def to_csv(self) -> str:
        cols = [m for m in self.metrics if m not in self.unavailable]
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["name", "pred", "ref", *cols])
        for p, vals in zip(self.pairs, self.values):
            w.writerow([p.name, p.pred, p.ref, *(_fmt(vals[c]) for c in cols)])
        w.writerow(["mean", "", "", *(_fmt(self.mean[c]) for c in cols)])
        return buf.getvalue()


def _json_num(v: float):
    """JSON has no infinity: PSNR of identical images is written as the string "inf".
    A value that could not be computed (NaN) is null."""
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


def _fmt(v: float) -> str:
    if math.isnan(v):
        return ""
    return "inf" if math.isinf(v) else f"{v:.6g}"


# ----------------------------------------------------------------------------- pairing
def _images(root: Path) -> dict[str, Path]:
    """Relative path without extension -> file, for every image under ``root``."""
    out: dict[str, Path] = {}
    for f in sorted(root.rglob("*")):
        if f.is_file() and f.suffix.lower() in IMAGE_EXTS and not f.name.startswith("."):
            key = f.relative_to(root).with_suffix("").as_posix()
            if key in out:
                raise InputError(
                    f"two images share the name {key!r}: {out[key].name} and {f.name}", where=str(root)
                )
            out[key] = f
    return out


def is_composite_output(root: Path) -> bool:
    """True when ``root`` holds job sub-folders with a report.json."""
    return any((d / "report.json").is_file() for d in root.iterdir() if d.is_dir())


def _unmatched_error(only_pred: list[str], only_ref: list[str], pred: Path, ref: Path) -> InputError:
    def names(keys):
        return ", ".join(keys[:10]) + (" ..." if len(keys) > 10 else "")

    lines = []
    if only_pred:
        lines.append(f"no reference in {ref} for: {names(only_pred)}")
    if only_ref:
        lines.append(f"no prediction in {pred} for: {names(only_ref)}")
    return InputError("missing pairs: " + "; ".join(lines))


def pair_folders(pred_dir, ref_dir, mask=None, background=None) -> list[Pair]:
    """Match images of two folders by relative path (extension ignored).

    ``mask``: a folder of per-image masks matched the same way, a single mask file
    used for every image, or None. ``background`` (shadow metrics): a folder of
    backgrounds matched the same way, or one file for every image. Raises InputError
    on any unmatched image.
    """
    pred_dir, ref_dir = Path(pred_dir), Path(ref_dir)
    for d in (pred_dir, ref_dir):
        if not d.is_dir():
            raise InputError("not a folder", where=str(d))
    p, r = _images(pred_dir), _images(ref_dir)
    if not p:
        raise InputError("no images found", where=str(pred_dir))
    only_p, only_r = sorted(set(p) - set(r)), sorted(set(r) - set(p))
    if only_p or only_r:
        raise _unmatched_error(only_p, only_r, pred_dir, ref_dir)
    masks = _mask_lookup(mask, list(p))
    bgs = _mask_lookup(background, list(p)) if background is not None else {}
    return [Pair(k, p[k], r[k], masks.get(k), bgs.get(k)) for k in sorted(p)]


def _mask_lookup(mask, keys: list[str]) -> dict[str, Path]:
    if mask is None:
        return {}
    m = Path(mask)
    if m.is_dir():
        found = _images(m)
        missing = [k for k in keys if k not in found]
        if missing:
            raise InputError(f"no mask for: {', '.join(missing[:10])}", where=str(m))
        return {k: found[k] for k in keys}
    if m.is_file():
        return {k: m for k in keys}
    raise InputError("mask not found (expected a folder of masks or a mask file)", where=str(m))


def _background_of_job(report: dict, job: Path) -> Path | None:
    """The scene photograph of a composite job, read from the manifest its report names."""
    try:
        from zcomp_cli.pipeline.manifest import load_manifest

        man = Path(report["job"]["manifest"])
        if not man.is_absolute():
            man = (job / man).resolve() if not man.is_file() else man
        spec = load_manifest(man, check_files=False).scenes[report["job"]["scene"]]
        return Path(spec.image) if Path(spec.image).is_file() else None
    except Exception:  # no manifest any more, or not one we can read: no background
        return None


def pair_composite_output(out_dir, refs=None, mask=None, background=None,
                          unscored: dict | None = None) -> list[Pair]:
    """Pairs of a ``zcomp composite`` output folder.

    The reference of a job is ``refs/<job>.*`` when ``refs`` is given, else
    ``report.json["reference"]``. ``mask`` is a folder (masks named by job), a file
    name inside each job folder (e.g. ``shading_mask.png``) or a single mask file.
    The prediction is ``composite.exr`` when the reference is a float file, else
    ``composite.png`` (either one when only one exists). The background (shadow
    metrics) is ``background`` (a folder of images named by job, or one file), else the
    scene image of the manifest named in ``report.json``; the object mask is
    ``object_mask.png`` beside the reference when there is one (``make-benchmark``
    writes it).

    With an ``unscored`` dict, jobs that cannot be paired (no reference, no composite)
    are listed there (name -> why) and the others are scored; without it, or when no
    job can be paired, they are an error.
    """
    bg_imgs = _images(Path(background)) if background is not None and Path(background).is_dir() else None
    out_dir = Path(out_dir)
    jobs = sorted(d for d in out_dir.iterdir() if d.is_dir() and (d / "report.json").is_file())
    if not jobs:
        raise InputError("no job folders with report.json", where=str(out_dir))
    ref_imgs = _images(Path(refs)) if refs is not None else None
    if refs is not None and not Path(refs).is_dir():
        raise InputError("not a folder", where=str(refs))
    pairs, problems = [], []
    for job in jobs:
        if ref_imgs is not None:
            ref = ref_imgs.get(job.name)
            if ref is None:
                problems.append(f"{job.name}: no image named {job.name}.* in {refs}")
                continue
        try:
            report = read_json_file(job / "report.json")
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read report.json: {exc}", where=str(job)) from exc
        if not isinstance(report, dict):
            report = {}
        if ref_imgs is None:
            ref_s = report.get("reference")
            if not ref_s:
                problems.append(f"{job.name}: report.json names no reference (use --refs DIR)")
                continue
            ref = Path(ref_s)
            if not ref.is_absolute():
                ref = (job / ref).resolve()
            if not ref.is_file():
                problems.append(f"{job.name}: reference {ref} not found")
                continue
        cands = [job / "composite.exr", job / "composite.png"]
        if ref.suffix.lower() not in FLOAT_EXTS:
            cands.reverse()
        pred = next((c for c in cands if c.is_file()), None)
        if pred is None:
            problems.append(f"{job.name}: no composite.exr or composite.png")
            continue
        if bg_imgs is not None:
            bg = bg_imgs.get(job.name)
        elif background is not None:
            bg = Path(background)
        else:
            bg = _background_of_job(report, job)
        om = ref.parent / "object_mask.png"
        pairs.append(Pair(job.name, pred, ref, _job_mask(job, mask), bg, om if om.is_file() else None))
    if problems and (unscored is None or not pairs):
        raise InputError("missing pairs:\n  " + "\n  ".join(problems), where=str(out_dir))
    if problems:
        for p in problems:
            name, why = p.split(": ", 1)
            unscored[name] = why
    return pairs


def _job_mask(job: Path, mask) -> Path | None:
    if mask is None:
        return None
    m = Path(mask)
    if m.is_dir():
        found = _images(m)
        if job.name not in found:
            raise InputError(f"no mask for job {job.name}", where=str(m))
        return found[job.name]
    if (job / str(mask)).is_file():
        return job / str(mask)
    if m.is_file():
        return m
    raise InputError(f"mask {mask} not found in the job folder", where=str(job))


# ----------------------------------------------------------------------------- scoring
class SizeMismatch(InputError):
    """A prediction and its reference differ in size (a composite made at another
    working resolution): that pair is left unscored, the others are scored."""


def load_pair(pair: Pair):
    """Read a pair as linear float32 H x W x 3 (plus mask H x W or None), checking sizes
    and finiteness with errors naming the files."""
    from zcomp_cli.imageio import read_alpha_or_grey, read_image

    pred, ref = read_image(pair.pred), read_image(pair.ref)
    for img, path in ((pred, pair.pred), (ref, pair.ref)):
        if not np.isfinite(img).all():
            raise InputError(f"{int((~np.isfinite(img)).sum())} non-finite values (NaN/Inf)", where=str(path))
    if pred.shape != ref.shape:
        raise SizeMismatch(
            f"size mismatch: {pair.pred} is {pred.shape[1]}x{pred.shape[0]}, "
            f"{pair.ref} is {ref.shape[1]}x{ref.shape[0]}"
        )
    mask = None
    if pair.mask is not None:
        mask = read_alpha_or_grey(pair.mask)
        if mask.shape != pred.shape[:2]:
            raise InputError(
                f"mask is {mask.shape[1]}x{mask.shape[0]}, image is {pred.shape[1]}x{pred.shape[0]}",
                where=str(pair.mask),
            )
        if not (mask > 0.5).any():
            raise InputError("mask selects no pixel", where=str(pair.mask))
    return pred, ref, mask


def score_pair(pair: Pair, metrics: list[str], *, linear: bool = False, lpips_model=None,
               region: str = "full", encoding: str = "srgb") -> dict[str, float]:
    """All requested metrics of one pair (metrics needing an absent model are skipped).

    ``region`` "object-crop" scores the object's grown box (``pair.object_mask``);
    ``encoding`` is the display encoding of the non-linear metrics ("srgb" or "gamma2.2",
    metrics/protocol.py)."""
    from zcomp_cli.metrics import flip as flip_mod
    from zcomp_cli.metrics import image_metrics as im
    from zcomp_cli.metrics import protocol
    from zcomp_cli.metrics.lpips import lpips_distance

    pred_lin, ref_lin, mask = load_pair(pair)
    box = None
    if region == "object-crop":
        box = _object_box(pair, pred_lin.shape[:2])
        pred_lin, ref_lin, mask = (protocol.crop(a, box) for a in (pred_lin, ref_lin, mask))
    pred_s, ref_s = protocol.encode(pred_lin, encoding), protocol.encode(ref_lin, encoding)
    p, r = (pred_lin, ref_lin) if linear else (pred_s, ref_s)
    fns = {"psnr": im.psnr, "rmse": im.rmse, "si-rmse": im.si_rmse, "ssim": im.ssim, "mae": im.mae}
    # HDR FLIP on two float files, unless a display encoding is the protocol (the paper's
    # figures are LDR FLIP of its 8-bit composites)
    hdr = (encoding == "srgb" and pair.pred.suffix.lower() in FLOAT_EXTS
           and pair.ref.suffix.lower() in FLOAT_EXTS)
    out: dict[str, float] = {}
    for m in metrics:
        try:
            if min(p.shape[:2]) < MIN_SIZE.get(m, 1):
                out[m] = float("nan")  # too small for this metric: no value, not an abort
            elif m in fns:
                out[m] = fns[m](p, r, mask)
            elif m == "flip":
                if hdr:
                    # HDR FLIP takes linear non-negative radiance; EXRs may hold tiny negatives.
                    out[m] = flip_mod.flip(
                        np.maximum(pred_lin, 0), np.maximum(ref_lin, 0), mask, mode="HDR"
                    )
                else:
                    out[m] = flip_mod.flip(pred_s, ref_s, mask, mode="LDR")
            elif m == "lpips" and lpips_model is not None:
                out[m] = lpips_distance(lpips_model, pred_s, ref_s, mask)
            elif m in SHADOW_METRICS and pair.background is not None:
                out[m] = _shadow_metric(m, pair, pred_lin, ref_lin, box)
        except InputError as exc:
            raise InputError(f"{m}: {exc}", where=f"{pair.pred} vs {pair.ref}") from exc
    return out


class Unscorable(InputError):
    """One pair cannot be scored under the asked protocol (its object mask missing,
    unreadable, empty, or its crop too small): listed as not scored, the rest go on."""


# An object crop smaller than this on a side is not scored: SSIM's window, and a PSNR of a
# handful of pixels (a 1-pixel crop identical to its reference made the mean inf).
MIN_OBJECT_CROP_PX = 7


def _object_box(pair: Pair, shape) -> tuple[int, int, int, int]:
    """The object crop of a pair, from ``object_mask.png`` beside its reference."""
    from zcomp_cli.imageio import read_alpha_or_grey
    from zcomp_cli.metrics.protocol import object_crop_box

    if pair.object_mask is None:
        raise Unscorable("--region object-crop needs the object's mask (object_mask.png beside the reference)",
                         where=str(pair.ref))
    try:
        om = read_alpha_or_grey(pair.object_mask)
        if om.shape != tuple(shape):
            raise InputError(f"object mask is {om.shape[1]}x{om.shape[0]}, image is {shape[1]}x{shape[0]}",
                             where=str(pair.object_mask))
        box = object_crop_box(om)
    except InputError as exc:
        raise Unscorable(str(exc)) from exc
    w, h = box[2] - box[0], box[3] - box[1]
    if min(w, h) < MIN_OBJECT_CROP_PX:
        raise Unscorable(f"its object crop is {w}x{h} px, under {MIN_OBJECT_CROP_PX}x{MIN_OBJECT_CROP_PX}: too "
                         "small to score", where=str(pair.object_mask))
    return box


def _shadow_metric(m: str, pair: Pair, pred_lin, ref_lin, box=None) -> float:
    from zcomp_cli.imageio import read_alpha_or_grey, read_image
    from zcomp_cli.metrics.protocol import crop
    from zcomp_cli.metrics.shadow import shadow_darkness, shadow_iou

    bg = read_image(pair.background)
    om = read_alpha_or_grey(pair.object_mask) if pair.object_mask is not None else None
    # the frame the images come from: before an object crop, the object mask's size
    full = pred_lin.shape if box is None else om.shape + (3,)
    if bg.shape != full:
        import cv2

        bg = cv2.resize(bg, (full[1], full[0]), interpolation=cv2.INTER_AREA)
    if om is not None and om.shape != full[:2]:
        om = None
    if box is not None:
        bg, om = crop(bg, box), crop(om, box)
    fn = shadow_iou if m == "shadow-iou" else shadow_darkness
    return fn(pred_lin, ref_lin, bg, om)


def evaluate(pairs: list[Pair], metrics: list[str], *, linear: bool = False,
             lpips_backbone=None, lpips_weights=None, on_pair=None, region: str = "full",
             encoding: str = "srgb") -> EvalResult:
    """Score every pair. LPIPS weights that cannot be loaded make only LPIPS
    unavailable (the reason is kept in ``EvalResult.unavailable``). ``region`` and
    ``encoding``: see ``score_pair``."""
    unavailable: dict[str, str] = {}
    model = None
    if "lpips" in metrics:
        from zcomp_cli.metrics.lpips import try_load_lpips

        st = try_load_lpips(lpips_backbone, lpips_weights)
        model = st.model
        if model is None:
            unavailable["lpips"] = st.reason or "unavailable"
        for note in getattr(model, "zcomp_notes", None) or []:
            log.warning("%s", note)
    no_bg = [p.name for p in pairs if p.background is None]
    for m in SHADOW_METRICS:
        if m in metrics and no_bg:
            unavailable[m] = (f"no background image for {', '.join(no_bg[:5])}"
                              f"{' ...' if len(no_bg) > 5 else ''} (give --background)")
    values = []
    scored, unscored = [], {}
    for pair in pairs:
        try:
            values.append(score_pair(pair, metrics, linear=linear, lpips_model=model, region=region,
                                     encoding=encoding))
        except SizeMismatch as exc:  # never resampled silently: listed, and the rest is scored
            unscored[pair.name] = f"{exc} (not scored: composite at another resolution?)"
            continue
        except Unscorable as exc:  # one bad object mask must not sink the evaluation
            unscored[pair.name] = f"{exc} (not scored)"
            continue
        scored.append(pair)
        if on_pair is not None:
            on_pair(pair, values[-1])
    if pairs and not scored:
        raise InputError("no pair could be scored:\n  " + "\n  ".join(f"{k}: {v}" for k, v in unscored.items()))
    pairs = scored
    mean = {}
    partial: dict[str, str] = {}
    for m in metrics:
        if m in unavailable:
            continue
        # inf (PSNR of an identical pair) propagates to the mean on purpose: hiding it
        # would overstate how far the other images are from their references.
        vals = [v[m] for v in values if m in v and not math.isnan(v[m])]
        skipped = [pr.name for pr, v in zip(pairs, values) if m in v and math.isnan(v[m])]
        if skipped:
            n = MIN_SIZE.get(m)
            why = f"images smaller than {n}x{n}" if n else "not computable"
            partial[m] = f"{why}: {', '.join(skipped[:10])}{' ...' if len(skipped) > 10 else ''}"
        if not vals:
            unavailable[m] = partial.pop(m, "no value")
            continue
        mean[m] = float(np.mean(vals))
    return EvalResult(list(metrics), list(pairs), values, mean, unavailable, linear, unscored=unscored,
                      partial=partial)



def write_outputs(result: EvalResult, prefix) -> tuple[Path, Path]:
    """Write ``<prefix>.csv`` and ``<prefix>.json`` atomically; return their paths."""
    from zcomp_cli.imageio import write_json_atomic, write_text_atomic

    prefix = Path(prefix)
    csv_path = prefix.parent / (prefix.name + ".csv")
    json_path = prefix.parent / (prefix.name + ".json")
    write_text_atomic(csv_path, result.to_csv())
    write_json_atomic(json_path, result.to_json())
    return csv_path, json_path
