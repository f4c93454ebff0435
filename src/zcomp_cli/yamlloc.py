"""YAML loading that remembers where each value came from, so that validation errors
can say ``jobs.yaml:12: jobs[1].pose.position: ...``."""

from __future__ import annotations

from pathlib import Path

import yaml

from zcomp_cli.errors import ManifestError


class LocDict(dict):
    """A dict with ``line`` (its own line) and ``key_lines`` (line of each key)."""

    line: int = 0
    key_lines: dict


class LocList(list):
    line: int = 0
    item_lines: list


class _Loader(yaml.SafeLoader):
    pass


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
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.load(f, Loader=_Loader)  # noqa: S506 - SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc)
        raise ManifestError(f"{where}: invalid YAML: {problem}") from exc
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
