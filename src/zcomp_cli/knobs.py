"""Configs declared once: each field with its default, its provenance and its valid range.

Every constant of the scene, the light fit and the renderers is a field of a frozen
config dataclass, declared with ``knob(default, kind, why, lo=..., hi=...)``: its **kind**
is one of ``KINDS`` (physical, statistical, sampling, fitted, heuristic, setting) and
**why** says where the value comes from -- a physical fact, a statistical convention, a
sampling resolution, a fitting script in ``benchmarks/`` (its output in ``docs/``), or a
judgement that no data has fixed yet (a heuristic, said as such). A nested config is a
field declared with ``sub(cls, why)``.

``from_mapping(cls, mapping, where)`` builds a config from plain values (a manifest's
``renderer:`` mapping, a calibration script's dict, the settings a ``report.json``
holds), checking each value against its field's type and range: what ``as_dict`` writes,
``from_mapping`` takes back (diffusers' ``save_config``/``from_config``). ``provenance``
lists every field of a config tree with its kind and why.

Lives at the bottom of the package: it imports only ``errors`` and ``limits``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import field

from zcomp_cli.errors import UsageError

KINDS = {
    "physical": "a physical fact or unit",
    "statistical": "a statistical convention",
    "sampling": "a sampling resolution: more costs time, not accuracy beyond it",
    "fitted": "fitted by a script in benchmarks/ on the development seeds",
    "heuristic": "a judgement no data has fixed yet",
    "setting": "the user's to set",
}

# The largest count any knob takes (samples, directions, widths, pixels): beyond it a
# setting is a typo or an attack, and the work it asks for has no bound a machine keeps.
MAX_COUNT = 1_000_000


def knob(default, kind: str, why: str, *, lo=None, hi=None, lo_open: bool | None = None, choices=None):
    """A config field: its default, its provenance ``kind`` (``KINDS``), ``why``, and its
    valid values: numbers within [``lo``, ``hi``] (``lo`` excluded when ``lo_open``;
    defaults: an integer at least 1 and at most ``MAX_COUNT``, a float above 0), the
    elements of a tuple likewise, a string among ``choices``. A default of None makes
    the field optional (None allowed) with the range given for its numbers."""
    if kind not in KINDS:
        raise ValueError(f"unknown provenance kind {kind!r} (known: {', '.join(KINDS)})")
    if not why or not why.strip():
        raise ValueError("a knob says why")
    return field(default=default, metadata={"kind": kind, "why": why, "lo": lo, "hi": hi, "lo_open": lo_open,
                                            "choices": None if choices is None else tuple(choices)})


def sub(cls, why: str):
    """A nested config field (``cls`` built from its defaults)."""
    return field(default_factory=cls, metadata={"kind": "config", "why": why})


def is_config(f: dataclasses.Field) -> bool:
    return f.metadata.get("kind") == "config"


def _shorten(v) -> str:
    from zcomp_cli.limits import shorten

    return shorten(v)


def _number(v, *, integer: bool, lo, hi, lo_open) -> tuple[bool, str]:
    """(ok, what is expected) of one number against its range."""
    if integer:
        lo = 1 if lo is None else lo
        hi = MAX_COUNT if hi is None else hi
        lo_open = bool(lo_open)
        want = ("a positive integer" + (f" (at most {hi})" if hi != MAX_COUNT else f" (at most {MAX_COUNT})")
                if (lo == 1 and not lo_open) else f"an integer in {'(' if lo_open else '['}{lo:g}, {hi}]")
        ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and float(v).is_integer()
    else:
        lo = 0.0 if lo is None else lo
        lo_open = (lo == 0.0 and lo_open is None) or bool(lo_open)
        want = ("a positive number" if (lo == 0 and lo_open and hi is None) else
                f"a number in {'(' if lo_open else '['}{lo:g}, {'inf)' if hi is None else f'{hi:g}]'}")
        ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
    if ok:
        x = float(v)
        ok = (x > lo if lo_open else x >= lo) and (hi is None or x <= hi)
    return ok, want


def check_value(f: dataclasses.Field, v, where: str):
    """``v`` checked against field ``f``'s type (its default's) and range; returns it
    converted (an int, a float, a tuple of floats). Raises ``UsageError`` naming
    ``where``."""
    md, default = f.metadata, f.default
    lo, hi, lo_open, choices = md.get("lo"), md.get("hi"), md.get("lo_open"), md.get("choices")
    if v is None and default is None:
        return None
    if choices is not None:
        if v not in choices:
            raise UsageError(f"{where}: expected one of {', '.join(map(str, choices))}, got {_shorten(v)}")
        return v
    if isinstance(default, bool):
        if not isinstance(v, bool):
            raise UsageError(f"{where}: expected true or false, got {_shorten(v)}")
        return v
    if isinstance(default, tuple):
        integer = bool(default) and all(isinstance(x, int) for x in default)
        lo_t = 0.0 if lo is None else lo
        ok = isinstance(v, (list, tuple)) and 0 < len(v) <= 64 and all(
            _number(x, integer=integer, lo=lo_t, hi=hi, lo_open=lo_open if lo_open is not None else False)[0]
            for x in v)
        if not ok:
            raise UsageError(f"{where}: expected a list of {'integers' if integer else 'numbers'} in "
                             f"[{lo_t:g}, {'inf' if hi is None else f'{hi:g}'}], got {_shorten(v)}")
        return tuple(int(x) if integer else float(x) for x in v)
    if isinstance(default, str):
        if not isinstance(v, str):
            raise UsageError(f"{where}: expected a string, got {_shorten(v)}")
        return v
    integer = isinstance(default, int)
    ok, want = _number(v, integer=integer, lo=lo, hi=hi, lo_open=lo_open)
    if not ok:
        raise UsageError(f"{where}: expected {want}, got {_shorten(v)}")
    return int(v) if integer else float(v)


def from_mapping(cls, value, label: str, path: str = ""):
    """A ``cls`` config from a mapping of its fields (or ``cls`` itself, kept), every
    value checked (``check_value``), nested configs from nested mappings. Messages name
    ``label`` and the field's dotted ``path`` (``physical renderer setting
    search.temperature: ...``); unknown names raise ``UsageError`` with the known ones."""
    if isinstance(value, cls):
        return value
    where = f"{label} {path.rstrip('.')}" if path else label
    if not isinstance(value, dict):
        raise UsageError(f"{where}: expected a mapping of {cls.__name__}'s fields, got {_shorten(value)}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    bad = [k for k in value if k not in fields]
    if bad:
        names = ", ".join(sorted(map(str, bad)))
        raise UsageError(f"unknown {label}(s): {names}; known: {', '.join(fields)}" if not path else
                         f"{where}: unknown field(s) {names}; known: {', '.join(fields)}")
    out = {}
    for k, v in value.items():
        f = fields[k]
        if is_config(f):
            out[k] = from_mapping(f.default_factory, v, label, f"{path}{k}.")
        else:
            out[k] = check_value(f, v, f"{label} {path}{k}")
    return cls(**out)


def as_dict(cfg) -> dict:
    """The config tree as plain values (tuples as lists): what ``from_mapping`` takes."""
    def plain(v):
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        return v

    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = as_dict(v) if dataclasses.is_dataclass(v) else plain(v)
    return out


def provenance(cfg) -> list[dict]:
    """Every field of a config tree: ``{"name", "value", "kind", "why"}`` (a nested
    field's name dotted: ``search.temperature``)."""
    out = []

    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out.append({"name": prefix + f.name, "value": v, "kind": f.metadata.get("kind"),
                            "why": f.metadata.get("why")})

    walk(cfg, "")
    return out


def config_classes(cls) -> list[type]:
    """``cls`` and every config class nested in it (depth first, each once)."""
    seen: list[type] = []

    def walk(c):
        if c in seen:
            return
        seen.append(c)
        for f in dataclasses.fields(c):
            if is_config(f):
                walk(f.default_factory)

    walk(cls)
    return seen


__all__ = ["KINDS", "MAX_COUNT", "knob", "sub", "is_config", "check_value", "from_mapping", "as_dict", "provenance",
           "config_classes"]
