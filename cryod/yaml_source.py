"""Reading YAML files so that every error can name the file, the line and the key.

Both the model file and the daemon configuration go through :class:`Section`:
each value is taken with its expected kind, unknown keys are refused, and an
error reads ``config/model.yaml:14: transfer_functions.ptc_to_flange.denominator:
...``.

Written here rather than taken from a schema library (pydantic, jsonschema): those check data
PyYAML has already built, by which time the keys' lines are gone and a duplicate key has
silently replaced the first. Here the checks run while the YAML nodes are at hand, so each
error points at its line, and the loader bounds what a hostile file can make it do (size,
nesting, aliases that expand).

Examples
--------
>>> section = Section.from_text("gain_K_per_W: 2.5\\nname: link\\n", "example.yaml")
>>> section.number("gain_K_per_W", minimum=0.0)
2.5
>>> section.text("name")
'link'
>>> section.finish()
"""

from __future__ import annotations

import math
import re
import reprlib
from collections.abc import Hashable
from pathlib import Path
from typing import Any, Iterable, Literal, overload

import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

from cryod.regular_files import NotARegularFile, open_regular_file

#: A number as these files write it: plain decimal digits with an optional sign, point and exponent
#: (``5``, ``-0.5``, ``.5``, ``2.5e-3``), which YAML 1.1 and YAML 1.2 read alike. A whole number with a
#: leading zero is not one (``010`` is octal 8 in YAML 1.1 and 10 in YAML 1.2), nor are underscores
#: (``1_2``), base 60 (``1:30``) and the ``0x``, ``0o``, ``0b`` forms: the loader keeps those as the text
#: written, and :meth:`Section.number` refuses them, saying what each YAML version would make of them.
_PLAIN_NUMBER = re.compile(r"[-+]?((0|[1-9][0-9]*)|[0-9]+\.[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?", re.ASCII)
#: Numbers in forms YAML 1.1 reads and YAML 1.2 reads otherwise or not at all: digits with underscores, base
#: 60 (colons), leading zeros; and the 0x, 0o, 0b prefixes.
_YAML_1_1_FORM = re.compile(r"[-+]?([0-9][0-9_:]*(\.[0-9_]*)?|0[xXoObB][0-9a-fA-F_]+)", re.ASCII)
_LEADING_ZERO = re.compile(r"[-+]?0[0-9]+", re.ASCII)
_BASE_PREFIX = re.compile(r"[-+]?0([xX]|[oO]|[bB])[0-9a-fA-F_]+", re.ASCII)
_BASE_NAMES = {"x": "hexadecimal", "o": "octal", "b": "binary"}
_OCTAL_MODE = re.compile(r"(0o)?[0-7]{1,4}", re.ASCII)

#: Largest YAML file read (bytes): a configuration or a model is a few kB.
MAX_FILE_BYTES = 1_000_000
#: Nodes that aliases (``*name``, merge keys ``<<: *name``) may add to a document in all:
#: enough to share a few settings, far too few for an anchor that expands exponentially
#: ("billion laughs"), which is refused while the file is read, before anything is built.
ALIAS_NODE_BUDGET = 1000
#: Deepest nesting of mappings and lists (a configuration nests 4 levels).
MAX_NESTING = 32
#: Longest key path and reason an error message carries (characters).
MAX_KEY_CHARS = 200
MAX_REASON_CHARS = 1000
_MERGE_TAG = "tag:yaml.org,2002:merge"


class _BoundedRepr(reprlib.Repr):
    """reprlib with the loader's dict subclass shown as a dict."""

    def repr1(self, x, level):
        if isinstance(x, dict) and type(x) is not dict:
            return self.repr_dict(x, level)
        return super().repr1(x, level)


_REPR = _BoundedRepr()
_REPR.maxlevel = 2
_REPR.maxdict = _REPR.maxlist = _REPR.maxtuple = _REPR.maxset = 5
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlong = 40


def shown(value: Any) -> str:
    """``repr(value)`` cut to a few dozen characters, for error messages.

    Whatever a file holds, the message that quotes it stays short: long
    texts, big numbers and deep or long lists are elided with ``...``.

    Examples
    --------
    >>> shown("0660")
    "'0660'"
    >>> shown(10 ** 400)
    '100000000000000000...0000000000000000000'
    >>> shown([[1, 2, 3, 4, 5, 6, 7, 8]] * 3)
    '[[1, 2, 3, 4, 5, ...], [1, 2, 3, 4, 5, ...], [1, 2, 3, 4, 5, ...]]'
    """
    return _REPR.repr(value)


def _digits(integer: int) -> str:
    try:
        return str(len(str(abs(integer))))
    except ValueError:                     # beyond Python's integer-to-text limit
        return "thousands of"


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else f"{text[:limit - 20]}...({len(text)} characters)"


class FileFormatError(ValueError):
    """A YAML file that cannot be used, with where and why.

    Attributes
    ----------
    source : str
        File name (or a description of the text's origin).
    line : int or None
        1-based line number of the offending key or value.
    key : str
        Dotted key path, empty for whole-file problems.
    reason : str
        What is wrong, in words a user can act on.

    Notes
    -----
    A key path longer than :data:`MAX_KEY_CHARS` or a reason longer than
    :data:`MAX_REASON_CHARS` is cut short: a message never carries more than a
    few lines of what a file holds.
    """

    def __init__(self, source: str, line: int | None, key: str, reason: str):
        self.source = source
        self.line = line
        self.key = _cut(key, MAX_KEY_CHARS)
        self.reason = _cut(reason, MAX_REASON_CHARS)
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {self.key + ': ' if self.key else ''}{self.reason}")


class _LocatedDict(dict):
    """A dict that remembers the line of itself and of each key (1-based)."""

    line: int | None = 0
    key_lines: dict[Hashable, int | None]


def _joined(path: str, label: str) -> str:
    if label.startswith("["):
        return path + label
    return f"{path}.{label}" if path else label


def _line(node_or_mark) -> int | None:
    mark = getattr(node_or_mark, "start_mark", node_or_mark)
    return mark.line + 1 if mark is not None else None


class _LocatingLoader(yaml.SafeLoader):
    """SafeLoader that records lines and key paths, refuses duplicate keys, and bounds the document.

    While composing, every node gets its dotted key path (``key_path``); nesting
    deeper than :data:`MAX_NESTING`, an alias inside its own anchor, and aliases
    that would add more than :data:`ALIAS_NODE_BUDGET` nodes are refused before
    any Python object is built. A value that a constructor cannot build (an
    impossible date, an integer too long to convert) is a :class:`FileFormatError`
    at its line.
    """

    def __init__(self, stream, source: str):
        super().__init__(stream)
        self.name = source
        self._path = [""]                   # key path of each node being composed, outermost first
        self._open_anchors: set = set()     # anchors whose node is still being composed
        self._alias_nodes = 0               # nodes added by aliases so far
        self._expanded_sizes: dict[int, int] = {}

    def error_at(self, where, key: str, reason: str) -> FileFormatError:
        return FileFormatError(self.name, _line(where), key, reason)

    def _label(self, parent, index) -> str | None:
        if isinstance(parent, SequenceNode):
            return f"[{index}]"
        if isinstance(parent, MappingNode):
            if index is None:
                return None                      # a key: located at its mapping
            return str(index.value) if isinstance(index, ScalarNode) else "?"
        return None

    def compose_node(self, parent, index):
        label = self._label(parent, index)
        path = self._path[-1] if label is None else _joined(self._path[-1], label)
        if len(self._path) > MAX_NESTING:
            raise self.error_at(self.peek_event().start_mark, path,
                                f"nested more than {MAX_NESTING} levels deep")
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            if event.anchor in self._open_anchors:
                raise self.error_at(event.start_mark, path,
                                    f"the alias *{event.anchor} is inside its own anchor &{event.anchor}: "
                                    f"it would never end")
            node = super().compose_node(parent, index)
            self._alias_nodes += self._expanded_size(node)
            if self._alias_nodes > ALIAS_NODE_BUDGET:
                raise self.error_at(event.start_mark, path,
                                    f"the alias *{event.anchor} makes the aliases of this file expand to more "
                                    f"than {ALIAS_NODE_BUDGET} values; share small settings with anchors, or "
                                    f"write the values out")
            return node
        anchor = event.anchor if isinstance(event, yaml.NodeEvent) else None
        if anchor is not None:
            self._open_anchors.add(anchor)
        self._path.append(path)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._path.pop()
            self._open_anchors.discard(anchor)
        node.key_path = path
        return node

    def _expanded_size(self, node) -> int:
        """Nodes in ``node`` with every alias in it written out (memoized: aliases share nodes)."""
        size = self._expanded_sizes.get(id(node))
        if size is None:
            if isinstance(node, SequenceNode):
                size = 1 + sum(self._expanded_size(item) for item in node.value)
            elif isinstance(node, MappingNode):
                size = 1 + sum(self._expanded_size(key) + self._expanded_size(value) for key, value in node.value)
            else:
                size = 1
            self._expanded_sizes[id(node)] = size
        return size

    def construct_object(self, node, deep=False):
        try:
            return super().construct_object(node, deep)
        except (FileFormatError, yaml.YAMLError):
            raise
        except (ValueError, TypeError, ArithmeticError) as error:
            raise self.error_at(node, getattr(node, "key_path", ""), _unreadable(node, error)) from None


def _unreadable(node, error: Exception) -> str:
    """Why a constructor could not build ``node``'s value, in the file's words."""
    kind = str(node.tag).rsplit(":", 1)[-1]
    text = node.value if isinstance(node, ScalarNode) else ""
    if kind == "int" and sum(character.isdigit() for character in text) > 30:
        return f"an integer of {sum(character.isdigit() for character in text)} digits is not a usable number"
    detail = f": {_cut(str(error), 200)}" if kind == "timestamp" else ""
    return f"{shown(text)} is not a valid {kind}{detail}"


def _construct_mapping(loader: _LocatingLoader, node: MappingNode) -> _LocatedDict:
    path = getattr(node, "key_path", "")
    written = {id(key_node) for key_node, _ in node.value if key_node.tag != _MERGE_TAG}
    loader.flatten_mapping(node)        # merged keys (<<: *name) first; the mapping's own keys override them
    mapping = _LocatedDict()
    mapping.line = _line(node)
    mapping.key_lines = {}
    own_keys = set()
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, Hashable):
            raise loader.error_at(key_node, path,
                                  f"a key must be a name, not a {'list' if isinstance(key, list) else 'mapping'} "
                                  f"({shown(key)})")
        if id(key_node) in written:
            if key in own_keys:
                raise loader.error_at(key_node, _joined(path, str(key)), "key given twice")
            own_keys.add(key)
        mapping[key] = loader.construct_object(value_node, deep=True)
        mapping.key_lines[key] = _line(key_node)
    return mapping


def _construct_number(loader: _LocatingLoader, node: ScalarNode):
    """A number as YAML builds it, but one of YAML 1.1's own forms (``010``, ``1_2``, ``1:30``, ``0x1F``) as
    the text written."""
    text = node.value
    if _YAML_1_1_FORM.fullmatch(text) and not _PLAIN_NUMBER.fullmatch(text):
        return text                        # Section.number says why it is not taken
    return yaml.SafeLoader.construct_yaml_int(loader, node) if node.tag.endswith(":int") \
        else yaml.SafeLoader.construct_yaml_float(loader, node)


_LocatingLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping
)
_LocatingLoader.add_constructor("tag:yaml.org,2002:int", _construct_number)
_LocatingLoader.add_constructor("tag:yaml.org,2002:float", _construct_number)


def _yaml_1_1_number(text: str) -> int | float | None:
    """What YAML 1.1 (PyYAML's reading) makes of a short number-like text, or None when not a number."""
    try:
        value = yaml.safe_load(text) if len(text) <= 40 else None
    except yaml.YAMLError:
        return None
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _not_plain_number(text: str) -> str:
    """Why ``text``, given where a number belongs, is not taken as one: what YAML versions make of it."""
    plain = "write it as plain decimal digits"
    read_1_1 = _yaml_1_1_number(text)
    if _LEADING_ZERO.fullmatch(text):
        decimal = int(text, 10)
        if read_1_1 is None:
            return f"{shown(text)} has a leading zero: YAML 1.2 reads it as {decimal}, YAML 1.1 as text; {plain}"
        return (f"{shown(text)} has a leading zero: YAML 1.1 reads it as octal {read_1_1}, YAML 1.2 as {decimal}; "
                f"write the number meant without the leading zero")
    prefix = _BASE_PREFIX.fullmatch(text)
    if prefix:
        try:
            value_text = f" ({int(text.replace('_', ''), 0)})"
        except ValueError:
            value_text = ""
        return f"{shown(text)} is {_BASE_NAMES[prefix.group(1).lower()]}: {plain}{value_text}"
    if read_1_1 is not None and "_" in text:
        return f"{shown(text)} has an underscore: YAML 1.1 reads it as {read_1_1}, YAML 1.2 as text; write {read_1_1}"
    if read_1_1 is not None and ":" in text:
        return (f"{shown(text)} is a base-60 number in YAML 1.1 ({read_1_1}) and text in YAML 1.2; "
                f"write {read_1_1}")
    return f"{shown(text)} is not a plain decimal number (e.g. 5, -0.5, 2.5e-3)"


def _parse(text: str, source: str) -> Any:
    if len(text) > MAX_FILE_BYTES:
        raise FileFormatError(source, None, "", f"{len(text)} characters: too long for a YAML file here "
                                                f"(at most {MAX_FILE_BYTES})")
    loader = None
    try:
        loader = _LocatingLoader(text, source)      # reads the text's characters at once
        return loader.get_single_data()
    except yaml.reader.ReaderError as error:
        line = text.count("\n", 0, error.position) + 1
        raise FileFormatError(source, line, "", f"character {error.character:#06x} is not allowed in "
                                                f"YAML ({error.reason})") from None
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        mark_line = mark.line + 1 if mark is not None else None
        raise FileFormatError(source, mark_line, "", f"not valid YAML: {error.problem}") from None
    except yaml.YAMLError as error:
        raise FileFormatError(source, None, "", f"not valid YAML: {error}") from None
    except RecursionError:
        raise FileFormatError(source, None, "", "nested too deeply to read") from None
    finally:
        if loader is not None:
            loader.dispose()


_MISSING = object()


def read_text_file(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """The text of a UTF-8 file of at most ``max_bytes``.

    Parameters
    ----------
    path : str or pathlib.Path
    max_bytes : int
        A larger file is refused (a configuration or model file is a few kB).

    Returns
    -------
    str

    Raises
    ------
    FileFormatError
        The file is missing, a directory, a named pipe, a device or a socket (refused without
        waiting on it), too large, unreadable or not UTF-8.
    """
    path = Path(path)
    try:
        with open_regular_file(path) as stream:
            data = stream.read(max_bytes + 1)
        if len(data) > max_bytes:
            raise FileFormatError(str(path), None, "", f"larger than {max_bytes} bytes: not a configuration "
                                                       f"or model file")
        return data.decode("utf-8")
    except FileNotFoundError:
        raise FileFormatError(str(path), None, "", "file not found") from None
    except NotARegularFile as error:
        raise FileFormatError(str(path), None, "", error.reason) from None
    except UnicodeDecodeError as error:
        raise FileFormatError(str(path), None, "", f"not UTF-8 text: {error}") from None
    except (OSError, ValueError) as error:          # ValueError: a NUL character in the path
        raise FileFormatError(str(path), None, "", f"cannot read: {error}") from None


class Section:
    """One YAML mapping being validated.

    Parameters
    ----------
    data : dict
        The mapping (as parsed by this module, so that lines are known).
    source : str
        File name, used in error messages.
    path : str
        Dotted key path of this mapping inside the file ('' at top level).
    """

    def __init__(self, data: dict, source: str, path: str = "", line: int | None = None):
        self.data = data
        self.source = source
        self.path = path
        self.line = line if line is not None else getattr(data, "line", None)
        self._taken: set[str] = set()

    # -- construction -----------------------------------------------------
    @classmethod
    def from_text(cls, text: str, source: str) -> "Section":
        """Parse YAML text whose top level must be a mapping."""
        data = _parse(text, source)
        if data is None:
            raise FileFormatError(source, None, "", "file is empty")
        if not isinstance(data, dict):
            raise FileFormatError(source, 1, "", "top level must be a mapping of keys to values")
        return cls(data, source)

    @classmethod
    def from_file(cls, path: str | Path) -> "Section":
        """Read and parse a YAML file; a missing or unreadable file is a FileFormatError."""
        return cls.from_text(read_text_file(path), str(path))

    # -- locations and errors -------------------------------------------
    def key_path(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def line_of(self, key: Any = None) -> int | None:
        key_lines = getattr(self.data, "key_lines", {})
        if key is not None and key in key_lines:
            return key_lines[key]
        return self.line

    def error(self, key: str | None, reason: str) -> FileFormatError:
        """An error located at ``key`` of this section (or at the section)."""
        return FileFormatError(
            self.source, self.line_of(key), self.key_path(key) if key else self.path, reason
        )

    def _get(self, key: str, default: Any) -> Any:
        self._taken.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise FileFormatError(
                self.source, self.line_of(None) if self.path else None,
                self.key_path(key), "missing required key",
            )
        return default

    # -- typed getters ----------------------------------------------------
    @overload
    def number(self, key: str, default: Any = ..., *, minimum: float | None = ..., maximum: float | None = ...,
               exclusive_minimum: bool = ..., integer: Literal[False] = ...) -> float: ...
    @overload
    def number(self, key: str, default: Any = ..., *, minimum: float | None = ..., maximum: float | None = ...,
               exclusive_minimum: bool = ..., integer: Literal[True]) -> int: ...

    def number(self, key: str, default: Any = _MISSING, *, minimum: float | None = None,
               maximum: float | None = None, exclusive_minimum: bool = False,
               integer: bool = False) -> float:
        """A finite number in plain decimal (int or float; '20e-6' style strings accepted).

        ``010``, ``1_2``, ``1:30``, ``0x1F`` are refused with what YAML 1.1 and 1.2 would read.
        """
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        number = self._as_number(key, value)
        if integer and number != int(number):
            raise self.error(key, f"must be a whole number, got {shown(value)}")
        if minimum is not None:
            if exclusive_minimum and not number > minimum:
                raise self.error(key, f"must be greater than {minimum:g}, got {number:g}")
            if not exclusive_minimum and number < minimum:
                raise self.error(key, f"must be at least {minimum:g}, got {number:g}")
        if maximum is not None and number > maximum:
            raise self.error(key, f"must be at most {maximum:g}, got {number:g}")
        return int(number) if integer else number

    def _as_number(self, key: str, value: Any) -> float:
        if isinstance(value, bool):
            raise self.error(key, f"must be a number, got {shown(value)}")
        if isinstance(value, str):
            text = value.strip()
            if not _PLAIN_NUMBER.fullmatch(text):
                raise self.error(key, f"must be a number: {_not_plain_number(text)}")
            value = float(text)
        if not isinstance(value, (int, float)):
            kind = "mapping" if isinstance(value, dict) else type(value).__name__
            raise self.error(key, f"must be a number, got {kind} {shown(value)}")
        try:
            number = float(value)
        except OverflowError:            # only an integer can be too large for a float
            raise self.error(key, f"must be a number of a sensible size, got an integer of "
                                  f"{_digits(int(value))} digits ({shown(value)})") from None
        if not math.isfinite(number):
            raise self.error(key, f"must be finite, got {shown(value)}")
        return number

    def numbers(self, key: str, default: Any = _MISSING, *, min_length: int = 1) -> list[float]:
        """A list of finite numbers."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list):
            raise self.error(key, f"must be a list of numbers, got {shown(value)}")
        if len(value) < min_length:
            raise self.error(key, f"needs at least {min_length} number(s)")
        return [self._as_number(key, item) for item in value]

    def text(self, key: str, default: Any = _MISSING, *, choices: Iterable[str] | None = None) -> str:
        """A string, optionally one of ``choices``."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be text, got {shown(value)}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(sorted(choices))}; got {shown(value)}")
        return value

    def texts(self, key: str, default: Any = _MISSING) -> list[str]:
        """A list of strings (at least one)."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list) or not value or not all(isinstance(item, str) for item in value):
            raise self.error(key, f"must be a list of text, got {shown(value)}")
        return list(value)

    def flag(self, key: str, default: Any = _MISSING) -> bool:
        """A boolean (true/false)."""
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {shown(value)}")
        return value

    def file_mode(self, key: str, default: Any = _MISSING) -> int:
        """A Unix file mode written in octal digits, e.g. "0660" (quoted or not; 660 too, as chmod reads it)."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        text = str(value).strip() if isinstance(value, (int, str)) and not isinstance(value, bool) else ""
        if _OCTAL_MODE.fullmatch(text):
            mode = int(text.removeprefix("0o"), 8)
        else:
            raise self.error(key, f"must be an octal file mode like \"0660\", got {shown(value)}")
        if not 0 <= mode <= 0o777:
            raise self.error(key, f"must be between 0000 and 0777, got {shown(value)}")
        return mode

    @overload
    def section(self, key: str) -> "Section": ...
    @overload
    def section(self, key: str, default: None) -> "Section | None": ...

    def section(self, key: str, default: Any = _MISSING) -> "Section | None":
        """A nested mapping; ``default=None`` makes it optional."""
        value = self._get(key, default)
        if value is None and default is None:
            return None
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping of keys to values, got {shown(value)}")
        return Section(value, self.source, self.key_path(key), self.line_of(key))

    def sections(self, key: str, default: Any = _MISSING) -> list["Section"]:
        """A list of mappings."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, got {shown(value)}")
        result = []
        for index, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.error(key, f"item {index} must be a mapping, got {shown(item)}")
            result.append(Section(item, self.source, f"{self.key_path(key)}[{index}]",
                                  getattr(item, "line", None)))
        return result

    def finish(self) -> None:
        """Refuse keys that were never asked for (typos, unsupported options)."""
        unknown = [key for key in self.data if key not in self._taken]
        if unknown:
            key = unknown[0]
            known = ", ".join(sorted(str(k) for k in self._taken)) or "none"
            raise FileFormatError(self.source, self.line_of(key), self.key_path(str(key)),
                                  f"unknown key (known keys here: {known})")
