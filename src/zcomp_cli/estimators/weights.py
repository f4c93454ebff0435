"""Local model folders: what a saved diffusers pipeline or transformers model must hold,
every file looked for when something is missing, and a fingerprint for the cache.

Nothing here imports torch, diffusers or transformers: the checks run when a manifest
is validated and before a model is loaded, so a missing file is reported by name
instead of surfacing as a library's traceback (or, worse, a download attempt).

A diffusers pipeline folder (``DiffusionPipeline.save_pretrained``) holds
``model_index.json`` and one sub-folder per component listed there:

* models (``UNet2DConditionModel``, ``AutoencoderKL``...): ``config.json`` and
  ``diffusion_pytorch_model[.<variant>].safetensors`` (or ``.bin``, or a sharded
  ``*.index.json``);
* transformers models (``CLIPTextModel``...): ``config.json`` and
  ``model[.<variant>].safetensors`` (or ``pytorch_model.bin``, or an index);
* schedulers: ``scheduler_config.json``;
* tokenizers: ``tokenizer.json``, or ``vocab.json`` + ``merges.txt`` (CLIP's BPE files).

A transformers model folder holds ``config.json``, its weights and, for the depth
models, ``preprocessor_config.json``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import WeightsError

MODEL_INDEX = "model_index.json"
DIFFUSERS_WEIGHTS = "diffusion_pytorch_model"
TRANSFORMERS_WEIGHTS = ("model", "pytorch_model")
WEIGHT_SUFFIXES = (".safetensors", ".bin")
# Variants the loader picks by itself when a folder holds only them (the Hub's Marigold
# repositories ship fp16 files beside the fp32 ones).
KNOWN_VARIANTS = ("fp16", "bf16")


@dataclass
class PipelineFolder:
    """A checked diffusers pipeline folder."""

    path: Path
    class_name: str
    index: dict  # model_index.json as read
    components: dict[str, tuple[str, str]]  # name -> (library, class)
    variant: str | None = None  # weight-file variant to load ("fp16"), None = plain names
    config: dict = field(default_factory=dict)  # the pipeline's own settings in the index


def _weight_names(stem: str, variant: str | None) -> list[str]:
    mid = f".{variant}" if variant else ""
    names = [f"{stem}{mid}{s}" for s in WEIGHT_SUFFIXES]
    names += [f"{stem}{s}.index{mid}.json" for s in WEIGHT_SUFFIXES]  # sharded, diffusers' naming
    names += [f"{stem}{mid}{s}.index.json" for s in WEIGHT_SUFFIXES]  # sharded, transformers' naming
    return names


def _stems(library: str) -> tuple[str, ...]:
    return (DIFFUSERS_WEIGHTS,) if library == "diffusers" else TRANSFORMERS_WEIGHTS


def _has_weights(folder: Path, library: str, variant: str | None) -> bool:
    return any((folder / n).is_file() for stem in _stems(library) for n in _weight_names(stem, variant))


def _kind(library: str, class_name: str) -> str:
    if "Scheduler" in class_name:
        return "scheduler"
    if "Tokenizer" in class_name:
        return "tokenizer"
    if "ImageProcessor" in class_name or "FeatureExtractor" in class_name:
        return "processor"
    return "model"


def _component_missing(root: Path, name: str, library: str, class_name: str,
                       variant: str | None) -> list[str]:
    """The files of one component that are not there, as paths (alternatives joined by ' or ')."""
    d = root / name
    kind = _kind(library, class_name)
    if kind == "scheduler":
        return [] if (d / "scheduler_config.json").is_file() else [str(d / "scheduler_config.json")]
    if kind == "tokenizer":
        if (d / "tokenizer.json").is_file() or ((d / "vocab.json").is_file() and (d / "merges.txt").is_file()):
            return []
        return [f"{d / 'tokenizer.json'} or {d / 'vocab.json'} + {d / 'merges.txt'}"]
    if kind == "processor":
        return [] if (d / "preprocessor_config.json").is_file() else [str(d / "preprocessor_config.json")]
    missing = []
    if not (d / "config.json").is_file():
        missing.append(str(d / "config.json"))
    if not _has_weights(d, library, variant):
        stem = _stems(library)[0]
        mid = f".{variant}" if variant else ""
        missing.append(f"{d / (stem + mid + '.safetensors')} (or .bin, or a sharded .index.json)")
    return missing


def _pick_variant(root: Path, comps: dict[str, tuple[str, str]], want: str | None) -> str | None:
    """The weight variant to load: ``want`` if given; else plain names when every model
    component has them, else the first known variant every model component has."""
    if want is not None:
        return want
    models = [(n, lib) for n, (lib, cls) in comps.items() if _kind(lib, cls) == "model"]
    if all(_has_weights(root / n, lib, None) for n, lib in models):
        return None
    for v in KNOWN_VARIANTS:
        if models and all(_has_weights(root / n, lib, v) for n, lib in models):
            return v
    return None


def read_pipeline_folder(path, *, what: str, variant: str | None = None) -> PipelineFolder:
    """Check a saved diffusers pipeline and return what its ``model_index.json`` says.

    Args:
        path: the folder given in the manifest (``model: DIR``).
        what: what it is for, for the messages ("normals model").
        variant: a weight-file variant to require ("fp16"); None picks one (see above).
    Raises:
        WeightsError: naming every file looked for and not found.
    """
    root = Path(path).expanduser()
    if not root.is_dir():
        raise WeightsError(f"{what}: {str(root)!r} is not a folder (looked for {root / MODEL_INDEX})")
    index_path = root / MODEL_INDEX
    if not index_path.is_file():
        raise WeightsError(f"{what}: {root} is not a saved diffusers pipeline; looked for {index_path}. "
                           + HOWTO)
    try:
        index = json.loads(index_path.read_text())
    except (OSError, ValueError) as exc:
        raise WeightsError(f"{what}: cannot read {index_path}: {exc}") from exc
    if not isinstance(index, dict):
        raise WeightsError(f"{what}: {index_path} is not a JSON mapping")
    comps: dict[str, tuple[str, str]] = {}
    config: dict = {}
    for k, v in index.items():
        if k.startswith("_"):
            continue
        if isinstance(v, list) and len(v) == 2 and all(isinstance(s, str) for s in v):
            comps[k] = (v[0], v[1])
        elif isinstance(v, list) and len(v) == 2 and v[0] is None:
            continue  # an optional component saved as absent
        else:
            config[k] = v
    chosen = _pick_variant(root, comps, variant)
    missing = []
    for name, (lib, cls) in comps.items():
        missing += _component_missing(root, name, lib, cls, chosen)
    if missing:
        raise WeightsError(f"{what}: the pipeline in {root} is incomplete; looked for and did not find:\n  - "
                           + "\n  - ".join(missing) + "\n" + HOWTO)
    return PipelineFolder(root, str(index.get("_class_name", "")), index, comps, chosen, config)


def folder_problem(path, what: str) -> str | None:
    """One line saying what a model folder lacks (every file looked for), or None when
    it holds a complete diffusers pipeline or transformers model. For the manifest's
    validation: no library is imported."""
    root = Path(path).expanduser()
    kind = folder_kind(root)
    if kind is None:
        return (f"{root} holds neither a diffusers pipeline (looked for {root / MODEL_INDEX}) nor a "
                f"transformers model (looked for {root / 'config.json'})")
    if kind == "diffusers":
        try:
            read_pipeline_folder(root, what=what)
        except WeightsError as exc:
            text = str(exc).split("\n" + HOWTO)[0]
            return text.replace(":\n  - ", ": ").replace("\n  - ", "; ")
        return None
    missing = []
    if not any((root / n).is_file() for stem in TRANSFORMERS_WEIGHTS for n in _weight_names(stem, None)):
        missing.append(str(root / "model.safetensors") + " (or pytorch_model.bin)")
    if what.startswith("depth") and not (root / "preprocessor_config.json").is_file():
        missing.append(str(root / "preprocessor_config.json"))
    return f"{what}: {root} lacks {', '.join(missing)}" if missing else None


def folder_kind(path) -> str | None:
    """``'diffusers'`` (a saved pipeline: model_index.json), ``'transformers'``
    (config.json at the top) or None (neither, or not a folder)."""
    p = Path(path).expanduser()
    if (p / MODEL_INDEX).is_file():
        return "diffusers"
    if (p / "config.json").is_file():
        return "transformers"
    return None


def fingerprint(path) -> str:
    """A short hash of a model folder for cache keys: the content of every JSON/text
    configuration file and the name, size and modification time of every other file
    (hashing gigabytes of weights on every run would cost more than the estimate)."""
    root = Path(path).expanduser()
    h = hashlib.sha256(str(root.resolve()).encode())
    for p in sorted(q for q in root.rglob("*") if q.is_file()):
        rel = str(p.relative_to(root)).encode()
        h.update(rel + b"\0")
        if p.suffix in (".json", ".txt") and p.stat().st_size < (1 << 20):
            h.update(p.read_bytes())
        else:
            st = p.stat()
            h.update(f"{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


HOWTO = ("Save the pipeline on a machine that can reach the Hub, e.g. "
         "`diffusers.MarigoldNormalsPipeline.from_pretrained('prs-eth/marigold-normals-v1-1')"
         ".save_pretrained(DIR)`, and copy DIR here; zcomp never downloads weights "
         "(docs/estimation.md).")
