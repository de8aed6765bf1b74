"""YAML read for the data files cobus takes (network descriptions, parameter sets, variable
lists): mappings and sequences that remember the line of each key and item, duplicate keys
and unreadable input reported as :class:`YamlProblem` with a line, never a bare exception.

Plain scalars are typed as YAML 1.2 types them, not as PyYAML's YAML 1.1 would, so that a
set-point means what it says: ``010`` is ten (not octal eight), ``1:30`` is text (not 90),
``no``/``on`` are text (only true/false are booleans); hex ``0x1A`` and octal ``0o17`` stay.
A number of more than 40 digits is refused (a value no CANopen type holds).

Anchors and aliases (``&defaults`` / ``<<: *defaults``) are read, but a document whose
aliases add more than :data:`MAX_ALIAS_VALUES` values to it (an "alias bomb": a few hundred
bytes that expand to gigabytes) or refer to themselves is refused before anything is built."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import yaml

from cobus.errors import CobusError, clip, listing

__all__ = [
    "MAX_ALIAS_VALUES",
    "MAX_TEXT",
    "DataFileError",
    "FileProblem",
    "LineMap",
    "LineSeq",
    "YamlProblem",
    "line_of",
    "milliseconds",
    "read_yaml",
]


#: The most values (scalars, mappings, sequences) the aliases of a document may add to it once
#: expanded (a 127-node network file holds about 10,000 values in all).
MAX_ALIAS_VALUES = 100_000


class LineMap(dict[Any, Any]):
    """A YAML mapping that remembers the line of each key."""

    line: int | None = None
    lines: dict[str, int]


class LineSeq(list[Any]):
    """A YAML sequence that remembers the line of each item."""

    line: int | None = None
    lines: list[int]


@dataclass(frozen=True)
class YamlProblem:
    """Why the text could not be read (``key``: a key given twice), and where."""

    line: int | None
    reason: str
    key: str | None = None


@dataclass(frozen=True)
class FileProblem:
    """One problem of a data file: where (file, line, key) and why."""

    path: str
    line: int | None
    key: str | None
    reason: str

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        key = "" if self.key is None else f" {clip(self.key, 80)}:"
        return f"{where}:{key} {clip(self.reason)}"


class DataFileError(CobusError, ValueError):
    """A data file that cannot be used; ``problems`` lists every one found."""

    #: How the message names the file.
    what: ClassVar[str] = "the file"

    def __init__(self, problems: Sequence[FileProblem]) -> None:
        self.problems = list(problems)
        head = f"{self.what} has {len(self.problems)} problem(s):"
        super().__init__(listing(head, [str(p) for p in self.problems]))


class _Loader(yaml.SafeLoader):
    duplicates: list[tuple[str, int]]


_BOOL, _INT, _FLOAT = (f"tag:yaml.org,2002:{t}" for t in ("bool", "int", "float"))
_Loader.yaml_implicit_resolvers = {
    first: [r for r in resolvers if r[0] not in (_BOOL, _INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    _BOOL, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")
)
_Loader.add_implicit_resolver(
    _INT, re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"), list("-+0123456789")
)
_Loader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
    ),
    list("-+.0123456789"),
)
_MAX_DIGITS = 40


def _construct_int(loader: _Loader, node: yaml.ScalarNode) -> int:
    text = str(loader.construct_scalar(node))
    digits = text.lstrip("+-")
    if len(digits) > _MAX_DIGITS:
        raise yaml.constructor.ConstructorError(
            None, None, f"a number of more than {_MAX_DIGITS} digits", node.start_mark
        )
    if digits[:2] in ("0x", "0X"):
        value = int(digits[2:], 16)
    elif digits[:2] in ("0o", "0O"):
        value = int(digits[2:], 8)
    else:
        value = int(digits, 10)
    return -value if text.startswith("-") else value


def _construct_map(loader: _Loader, node: yaml.MappingNode) -> LineMap:
    loader.flatten_mapping(node)
    out = LineMap()
    out.line = node.start_mark.line + 1
    out.lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if isinstance(key, list | dict):
            raise yaml.constructor.ConstructorError(
                None,
                None,
                "a key must be a plain value, not a list or a mapping",
                key_node.start_mark,
            )
        if key in out:
            loader.duplicates.append((str(key), line))
        out[key] = loader.construct_object(value_node, deep=True)
        out.lines[str(key)] = line
    return out


def _construct_seq(loader: _Loader, node: yaml.SequenceNode) -> LineSeq:
    out = LineSeq(loader.construct_object(item, deep=True) for item in node.value)
    out.line = node.start_mark.line + 1
    out.lines = [item.start_mark.line + 1 for item in node.value]
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_map)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_seq)
_Loader.add_constructor(_INT, _construct_int)


def line_of(container: Any, key: Any) -> int | None:
    """The line of ``key`` in a :class:`LineMap` (an index in a :class:`LineSeq`), else the
    container's own line, else None."""
    if isinstance(container, LineMap):
        return container.lines.get(str(key), container.line)
    if isinstance(container, LineSeq) and isinstance(key, int) and key < len(container.lines):
        return container.lines[key]
    return None


#: The most characters a data file may hold: a 127-node network file has about 100,000; PyYAML
#: reads some 4 MB a second, so 100 MB would cost half a minute.
MAX_TEXT = 16 * 1024 * 1024


def read_yaml(text: str) -> tuple[Any, list[YamlProblem]]:
    """The data of ``text`` and the problems found (data None when it cannot be read;
    duplicate keys are problems too, the data then holds the second value)."""
    if len(text) > MAX_TEXT:
        return None, [
            YamlProblem(
                None,
                f"{len(text):,} characters, more than the {MAX_TEXT:,} a cobus data file may "
                "hold: is it the right file?",
            )
        ]
    loader: _Loader | None = None
    try:
        loader = _Loader(text)  # (the reader refuses control characters here already)
        loader.duplicates = []
        node = loader.get_single_node()
        if node is not None:
            refused = _expansion_problem(node)
            if refused is not None:
                return None, [refused]
        data = loader.construct_document(node) if node is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        if isinstance(exc, yaml.reader.ReaderError):
            line = text.count("\n", 0, exc.position) + 1
            problem = (
                f"character 0x{exc.character:X} is not allowed in YAML (a control character?)"
                if isinstance(exc.character, int)
                else str(exc)
            )
        else:
            problem = getattr(exc, "problem", None) or str(exc)
        return None, [YamlProblem(line, f"not valid YAML: {problem}")]
    except RecursionError:
        return None, [YamlProblem(None, "not valid YAML: nested too deeply to read")]
    finally:
        if loader is not None:
            loader.dispose()
    problems = [
        YamlProblem(line, "the key is given twice (the second would silently win)", key)
        for key, line in loader.duplicates
    ]
    return data, problems


def _expansion_problem(root: yaml.Node) -> YamlProblem | None:
    """Why the node graph of a document must not be built: its aliases add more than
    :data:`MAX_ALIAS_VALUES` values to it, or one refers to a value it is part of."""
    sizes: dict[int, int] = {}  # id(node) -> values in it, aliases expanded
    open_: set[int] = set()
    # An explicit stack (a deep document must not cost Python's recursion): (node, children
    # done); a node is summed once its children are.
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            open_.discard(key)
            total = 1 + sum(sizes[id(child)] for child in _children(node))
            if total > MAX_ALIAS_VALUES + len(sizes) + 1:  # (more than its own values)
                return YamlProblem(
                    node.start_mark.line + 1,
                    f"the aliases (*name) add more than {MAX_ALIAS_VALUES:,} values to this "
                    "document (an alias bomb?): write the values out, or use fewer aliases "
                    "of aliases",
                )
            sizes[key] = total
            continue
        if key in sizes:
            continue
        if key in open_:
            return YamlProblem(
                node.start_mark.line + 1,
                "an alias (*name) refers to a value it is part of: a value cannot hold itself",
            )
        open_.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in open_:
                return YamlProblem(
                    child.start_mark.line + 1,
                    "an alias (*name) refers to a value it is part of: a value cannot hold itself",
                )
            if id(child) not in sizes:
                stack.append((child, False))
    return None


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


_DURATION = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*(us|µs|ms|s)?\s*\Z")
_UNIT_MS = {"us": 0.001, "µs": 0.001, "ms": 1.0, "s": 1000.0, None: 1.0}


def milliseconds(value: Any, high: float = 1e9) -> float:
    """A duration in milliseconds from a data file: a number (ms) or text with a unit
    (``"1.5 s"``, ``"500 us"``); ValueError says why not."""
    if isinstance(value, str):
        match = _DURATION.match(value)
        if match is None:
            raise ValueError(
                f"{value!r} is not a duration: write milliseconds or e.g. '1.5 s', '500 us'"
            )
        ms = float(match.group(1)) * _UNIT_MS[match.group(2)]
    elif isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ValueError(f"{value!r} is not a duration in milliseconds")
    else:
        ms = float(value)
    if not 0 <= ms <= high:
        raise ValueError(f"{ms:g} ms is out of range: use 0..{high:g} ms")
    return ms
