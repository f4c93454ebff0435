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

import contextlib
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


# A configuration file larger than this is not a model's configuration (the largest of
# the Hub's model_index.json and config.json are a few tens of KB; a tokenizer.json is
# not read here).
MAX_CONFIG_BYTES = 4 << 20
# The libraries whose own classes a folder may name: anything else is the folder's code.
KNOWN_LIBRARIES = ("diffusers", "transformers")
# Keys by which a configuration asks its library to import the folder's own code.
CODE_KEYS = ("auto_map", "custom_pipeline")
# A safetensors header larger than this is refused (the largest real ones, thousands of
# tensors, are a few MB)
MAX_SAFETENSORS_HEADER = 100 << 20
# A weights file whose blocks on disk hold less than this share of its size is sparse
# (holes read as zeros): not weights anyone saved
MIN_ALLOCATED_SHARE = 0.5
SAFETENSORS_DTYPE_BYTES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2, "I8": 1,
                           "U8": 1, "BOOL": 1, "F8_E4M3": 1, "F8_E5M2": 1, "U16": 2, "U32": 4, "U64": 8}


@contextlib.contextmanager
def quiet_loading(hf_logging):
    """Within the block, a Hugging Face library's load-time chatter and progress bars
    (transformers' "Loading weights", diffusers' per-component bars) are off, whatever
    ``-q`` says: zcomp's own progress shows the stage. ``hf_logging``:
    ``transformers.utils.logging`` or ``diffusers.utils.logging``."""
    verbosity, bars = hf_logging.get_verbosity(), hf_logging.is_progress_bar_enabled()
    hf_logging.set_verbosity_error()
    hf_logging.disable_progress_bar()
    try:
        yield
    finally:
        hf_logging.set_verbosity(verbosity)
        if bars:
            hf_logging.enable_progress_bar()


def read_config(path, what: str) -> dict:
    """A JSON configuration file as a mapping, bounded: at most ``MAX_CONFIG_BYTES``,
    any nesting a JSON parser takes without exhausting Python's stack. Raises
    ``WeightsError`` naming the file otherwise."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise WeightsError(f"{what}: {path} is {size} bytes, over the {MAX_CONFIG_BYTES} a configuration "
                               "file may be")
        with open(path, "rb") as f:
            data = json.loads(f.read(MAX_CONFIG_BYTES + 1).decode("utf-8"))
    except WeightsError:
        raise
    except RecursionError:
        raise WeightsError(f"{what}: {path} is nested too deeply to be a configuration file") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise WeightsError(f"{what}: cannot read {path}: {exc}") from None
    if not isinstance(data, dict):
        raise WeightsError(f"{what}: {path} is not a JSON mapping")
    return data


def custom_code_problem(path, what: str) -> str | None:
    """Why a model folder would make its library run code it ships (None when it would
    not): Python files in it, a configuration that names classes to import from it
    (``auto_map``, ``custom_pipeline``) or a pipeline component from a library other than
    diffusers and transformers. zcomp never runs a model folder's code (every load passes
    ``trust_remote_code=False``); such a folder is refused before anything runs."""
    root = Path(path).expanduser()
    try:
        code = sorted(str(p.relative_to(root)) for p in root.rglob("*.py"))
    except OSError as exc:
        return f"{what}: cannot list {root}: {exc.strerror or exc}"
    if code:
        more = f" and {len(code) - 3} more" if len(code) > 3 else ""
        return (f"{what}: {root} holds Python code ({', '.join(code[:3])}{more}): zcomp never runs a model "
                "folder's own code; keep only the configuration and weight files")
    configs = [root / MODEL_INDEX, root / "config.json"] + sorted(root.glob("*/config.json")) \
        + sorted(root.glob("*/*_config.json")) + sorted(root.glob("*_config.json"))
    for cfg in configs:
        if not cfg.is_file():
            continue
        try:
            data = read_config(cfg, what)
        except WeightsError as exc:
            return str(exc)
        keys = [k for k in CODE_KEYS if k in data]
        if keys:
            return (f"{what}: {cfg} names code to import from the folder ({keys[0]}): zcomp never runs a "
                    "model folder's own code (trust_remote_code is off)")
        if cfg.name == MODEL_INDEX:
            for name, v in data.items():
                if name.startswith("_") or not (isinstance(v, list) and len(v) == 2 and isinstance(v[0], str)):
                    continue
                if v[0] not in KNOWN_LIBRARIES:
                    return (f"{what}: {cfg} takes component {name!r} from {v[0]!r}, not from diffusers or "
                            "transformers: that is the folder's own code, which zcomp never runs")
    return None


def weights_file_problem(path) -> str | None:
    """Why a weights file cannot be what it claims (None when it may be), from its size
    and header alone: empty, sparse (its size far beyond the blocks it holds on disk), a
    safetensors file whose header is absurd, unreadable or points past the file's end."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError as exc:
        return f"{path}: {exc.strerror or exc}"
    if st.st_size == 0:
        return f"{path} is empty"
    allocated = getattr(st, "st_blocks", None)
    if allocated is not None and st.st_size > (64 << 20) and allocated * 512 < MIN_ALLOCATED_SHARE * st.st_size:
        return (f"{path} is sparse: {st.st_size / 2**30:.1f} GB long but {allocated * 512 / 2**20:.0f} MB on "
                "disk (holes read as zeros): not a saved model")
    if path.suffix != ".safetensors" or path.name.endswith(".index.json"):
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(8)
            if len(head) < 8:
                return f"{path} is truncated: no safetensors header"
            n = int.from_bytes(head, "little")
            if n > MAX_SAFETENSORS_HEADER or n > st.st_size - 8:
                return f"{path}: its safetensors header claims {n} bytes (the file has {st.st_size})"
            header = json.loads(f.read(n).decode("utf-8"))
    except RecursionError:
        return f"{path}: its safetensors header is nested too deeply"
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        return f"{path}: unreadable safetensors header ({type(exc).__name__}: {exc})"
    if not isinstance(header, dict):
        return f"{path}: its safetensors header is not a mapping"
    data_len = st.st_size - 8 - n
    for name, t in header.items():
        if name == "__metadata__":
            continue
        try:
            lo, hi = (int(v) for v in t["data_offsets"])
            count = 1
            for d in t["shape"]:
                count *= int(d)
            want = count * SAFETENSORS_DTYPE_BYTES[t["dtype"]]
        except (TypeError, KeyError, ValueError):
            return f"{path}: tensor {str(name)[:80]!r} has no valid dtype, shape and data_offsets in its header"
        if not (0 <= lo <= hi <= data_len) or hi - lo != want:
            return (f"{path}: tensor {str(name)[:80]!r} claims bytes {lo}-{hi} ({want} for its shape) of "
                    f"{data_len}: truncated or damaged")
    return None


def weight_files(root) -> list[Path]:
    """The weight files of a model folder and its components (every suffix and variant)."""
    root = Path(root)
    out = []
    for d in [root] + sorted(p for p in root.iterdir() if p.is_dir()):
        out += sorted(p for p in d.iterdir() if p.is_file() and p.suffix in WEIGHT_SUFFIXES)
    return out


def check_folder_safety(path, what: str) -> None:
    """Raise ``WeightsError`` when a model folder would run its own code
    (``custom_code_problem``) or holds a weights file that cannot be one
    (``weights_file_problem``): before any library reads it."""
    bad = custom_code_problem(path, what)
    if bad is None:
        for w in weight_files(Path(path).expanduser()):
            why = weights_file_problem(w)
            if why:
                bad = f"{what}: {why}"
                break
    if bad:
        raise WeightsError(bad)


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
    check_folder_safety(root, what)
    index = read_config(index_path, what)
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
    if kind == "transformers":  # (a pipeline's is read_pipeline_folder's own first check)
        try:
            check_folder_safety(root, what)
        except WeightsError as exc:
            return str(exc)
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
