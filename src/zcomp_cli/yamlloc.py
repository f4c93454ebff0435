"""YAML loading that remembers where each value came from, so that validation errors
can say ``jobs.yaml:12: jobs[1].pose.position: ...``.

Hostile input is bounded: the file size is capped (``limits.max_manifest_bytes``) and
so is the number of values the document expands to with its aliases
(``limits.max_yaml_nodes``), which refuses "billion laughs" alias bombs before they
are built. Floats are read as YAML 1.2 reads them: ``1e9`` is a number (YAML 1.1,
PyYAML's default, wants ``1.0e+9`` and reads ``1e9`` as a string)."""

from __future__ import annotations

from pathlib import Path

import re

import yaml

from zcomp_cli.errors import ManifestError
from zcomp_cli.limits import MAX_MANIFEST_BYTES_ENV, MAX_YAML_NODES_ENV, max_manifest_bytes, max_yaml_nodes


class LocDict(dict):
    """A dict with ``line`` (its own line) and ``key_lines`` (line of each key)."""

    line: int = 0
    key_lines: dict


class LocList(list):
    line: int = 0
    item_lines: list


# libyaml's parser when PyYAML has it (about 10x faster than the pure-Python one: a
# 4 MiB manifest loads in seconds, not minutes); the constructors below are the same.
_Base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(_Base):
    def construct_document(self, node):
        _check_expansion(node, max_yaml_nodes())
        return super().construct_document(node)


class _TooBig(yaml.YAMLError):
    def __init__(self, problem: str, mark=None):
        super().__init__(problem)
        self.problem = problem
        self.problem_mark = mark


def _check_expansion(root, limit: int) -> None:
    """Count the values ``root`` expands to (an alias counts its whole target each time
    it is used) without expanding anything; refuse recursive aliases and documents
    past ``limit``."""
    sizes: dict[int, int] = {}
    on_stack: set[int] = set()
    # Iterative post-order walk: a deep document must not hit Python's recursion limit.
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = ()
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if done:
            on_stack.discard(key)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[key] > limit:
                raise _TooBig(f"the document expands to more than {limit:,} values (an alias bomb?); "
                              f"set ${MAX_YAML_NODES_ENV} to raise the limit", node.start_mark)
            continue
        if key in sizes:
            continue
        if key in on_stack:
            raise _TooBig("recursive alias (a value that contains itself)", node.start_mark)
        on_stack.add(key)
        stack.append((node, True))
        for c in children:
            if id(c) in on_stack:
                raise _TooBig("recursive alias (a value that contains itself)", c.start_mark)
            if id(c) not in sizes:
                stack.append((c, False))


# Every float of YAML 1.2's core schema that YAML 1.1 (PyYAML) reads as a string: an
# exponent without a sign ("1e9", "1.0e6", "1.5E3", ".5e3") or without a dot ("-2E-3").
# (Integers keep PyYAML's resolver: a float needs a dot or an exponent.)
YAML12_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", YAML12_FLOAT, list("-+.0123456789"))


def _construct_mapping(loader, node, deep=False):
    loader.flatten_mapping(node)
    d = LocDict()
    d.line = node.start_mark.line + 1
    d.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None, None, f"unhashable key {key!r}", key_node.start_mark
            )
        if key in d:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        d[key] = loader.construct_object(value_node, deep=True)
        d.key_lines[key] = key_node.start_mark.line + 1
    return d


def _construct_sequence(loader, node, deep=False):
    lst = LocList(loader.construct_object(child, deep=True) for child in node.value)
    lst.line = node.start_mark.line + 1
    lst.item_lines = [child.start_mark.line + 1 for child in node.value]
    return lst


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)


def load_yaml(path) -> object:
    """Load a YAML file with location info; syntax errors become ManifestError."""
    path = Path(path)
    if not path.is_file():
        raise ManifestError(f"file not found: {path}")
    limit = max_manifest_bytes()
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read: {exc}") from exc
    if size > limit:
        raise ManifestError(f"{path}: {size:,} bytes is larger than the {limit:,}-byte limit for a manifest "
                            f"(set ${MAX_MANIFEST_BYTES_ENV} to raise it)")
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.load(f, Loader=_Loader)  # noqa: S506 - SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc)
        if len(problem) > 200:  # PyYAML quotes the offending text, which can be huge
            problem = problem[:197] + "..."
        raise ManifestError(f"{where}: invalid YAML: {problem}") from exc
    except RecursionError as exc:
        raise ManifestError(f"{path}: invalid YAML: nested too deeply") from exc
    except UnicodeDecodeError as exc:
        raise ManifestError(f"{path}: not a text file: {exc}") from exc
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read: {exc}") from exc


def line_of(container, key=None) -> int | None:
    """Line of ``container[key]`` (or of the container itself)."""
    if key is None:
        return getattr(container, "line", None)
    if isinstance(container, LocDict):
        return container.key_lines.get(key, container.line)
    if isinstance(container, LocList) and isinstance(key, int) and 0 <= key < len(container.item_lines):
        return container.item_lines[key]
    return getattr(container, "line", None)
