"""Resource limits on untrusted input, checked before anything large is allocated.

Every limit has a default that fits a laptop and an environment variable to raise it
(documented in ``docs/limits.md``):

=====================  ==========================  ==========================================
limit                  environment variable        default
=====================  ==========================  ==========================================
pixels per image       ``ZCOMP_MAX_PIXELS``         40,000,000 (e.g. 8000 x 5000)
manifest file size     ``ZCOMP_MAX_MANIFEST_BYTES`` 4 MiB
YAML values expanded   ``ZCOMP_MAX_YAML_NODES``     2,000,000 (aliases counted at each use)
=====================  ==========================  ==========================================

A job at P pixels holds a few dozen float32 maps of P pixels at once (image, depth,
normals, albedo, shading, two renders, masks...), about 0.3 KB per pixel
(``BUDGET_KB_PER_PIXEL``): the default pixel budget keeps one job near 12 GB at worst. A
renderer that costs more a pixel declares it (``RendererEntry.kb_per_pixel``) and its
jobs' working size is budgeted by it (``renderer_budget_problem``).
"""

from __future__ import annotations

import os

from zcomp_cli.errors import UsageError

MAX_PIXELS_ENV = "ZCOMP_MAX_PIXELS"
MAX_MANIFEST_BYTES_ENV = "ZCOMP_MAX_MANIFEST_BYTES"
MAX_YAML_NODES_ENV = "ZCOMP_MAX_YAML_NODES"

DEFAULT_MAX_PIXELS = 40_000_000
DEFAULT_MAX_MANIFEST_BYTES = 4 * 1024 * 1024
DEFAULT_MAX_YAML_NODES = 2_000_000

# Longest job / scene / object name (it becomes a folder name; file systems stop at 255
# bytes and the default job name joins a scene and an object name).
MAX_NAME_LEN = 100
# Longest value quoted back in an error message.
MAX_SHOWN_CHARS = 80
# Longest text zcomp writes or shows in one field of a summary, a status line or a
# report page (a failure reason, a job name): a reason is a few hundred characters; a
# 100 MB one (a plugin's exception) made a 600 MB page and a status that printed for
# minutes.
MAX_FIELD_CHARS = 2000


def _env_int(name: str, default: int) -> int:
    raw = os.environ.get(name)
    if raw is None or raw.strip() == "":
        return default
    try:
        value = int(float(raw))
    except ValueError:
        raise UsageError(f"${name} must be a positive integer, got {raw[:MAX_SHOWN_CHARS]!r}") from None
    if value < 1:
        raise UsageError(f"${name} must be a positive integer, got {raw[:MAX_SHOWN_CHARS]!r}")
    return value


def max_pixels() -> int:
    """Largest image (width x height) zcomp reads, renders or resamples to."""
    return _env_int(MAX_PIXELS_ENV, DEFAULT_MAX_PIXELS)


def max_manifest_bytes() -> int:
    return _env_int(MAX_MANIFEST_BYTES_ENV, DEFAULT_MAX_MANIFEST_BYTES)


def max_yaml_nodes() -> int:
    return _env_int(MAX_YAML_NODES_ENV, DEFAULT_MAX_YAML_NODES)


# What the pixel budget is set for: a job's memory per pixel of its working size (the
# physical renderer's: 1.1 GB at 2048 x 1536, issue 50).
BUDGET_KB_PER_PIXEL = 0.3


def renderer_budget_problem(width: int, height: int, kb_per_pixel: float, renderer: str) -> str | None:
    """None when a job of ``width x height`` working pixels on a renderer costing
    ``kb_per_pixel`` fits the memory the pixel budget stands for (``max_pixels`` x
    ``BUDGET_KB_PER_PIXEL``), else why, naming how to raise it."""
    limit = int(max_pixels() * BUDGET_KB_PER_PIXEL / max(float(kb_per_pixel), BUDGET_KB_PER_PIXEL))
    if int(width) * int(height) <= limit:
        return None
    return (f"{int(width)}x{int(height)} = {int(width) * int(height):,} working pixels exceeds the {renderer} "
            f"renderer's budget of {limit:,} (it holds about {kb_per_pixel:g} KB a pixel, where the pixel budget "
            f"of {max_pixels():,} is set for {BUDGET_KB_PER_PIXEL:g}; set ${MAX_PIXELS_ENV} to raise it, or a "
            "smaller defaults.resolution)")


def pixel_budget_problem(width: int, height: int) -> str | None:
    """None when ``width x height`` fits the pixel budget, else a message naming the
    limit and how to raise it (the caller names the field)."""
    limit = max_pixels()
    if int(width) * int(height) <= limit:
        return None
    return (f"{int(width)}x{int(height)} = {int(width) * int(height):,} pixels exceeds the pixel budget of "
            f"{limit:,} (set ${MAX_PIXELS_ENV} to raise it)")


def printable(text) -> str:
    """``text`` on one line of valid UTF-8: control characters (a newline in a folder
    name) and the undecodable bytes of a non-UTF-8 path (surrogate escapes) written as
    backslash escapes, everything else kept (an accented name stays readable)."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in str(text))


def field_text(text, limit: int = MAX_FIELD_CHARS) -> str:
    """``text`` as a summary, a status line or a page shows it: cut to ``limit``
    characters (saying how many more there were) before anything else reads it, and
    each of its lines ``printable``."""
    text = str(text)
    more = f"... ({len(text) - limit:,} more characters)" if len(text) > limit else ""
    return "\n".join(printable(line) for line in text[:limit].split("\n")) + more


def shorten(value, limit: int = MAX_SHOWN_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters, for error messages: a manifest value
    can be megabytes long (or an alias bomb). YAML containers are named as YAML names
    them (mapping, list), not by their Python class."""
    text = _repr_bounded(value, limit + 1)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _repr_bounded(value, budget: int) -> str:
    # Never build the full repr of a huge (or alias-shared) structure: stop at budget.
    if isinstance(value, dict):
        parts, used = [], 1
        for k, v in value.items():
            if used > budget:
                parts.append("...")
                break
            s = f"{_repr_bounded(k, budget - used)}: {_repr_bounded(v, budget - used)}"
            parts.append(s)
            used += len(s) + 2
        return "{" + ", ".join(parts) + "}"
    if isinstance(value, (list, tuple)):
        parts, used = [], 1
        for v in value:
            if used > budget:
                parts.append("...")
                break
            s = _repr_bounded(v, budget - used)
            parts.append(s)
            used += len(s) + 2
        return "[" + ", ".join(parts) + "]"
    if isinstance(value, str) and len(value) > budget:
        return repr(value[:budget])
    return repr(value)


def type_name(value) -> str:
    """A YAML-level name of a value's type, for messages ("a list", not "LocList")."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (int, float)):
        return "a number"
    if value is None:
        return "null"
    return type(value).__name__
