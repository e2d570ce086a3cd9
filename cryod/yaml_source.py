"""Reading YAML files so that every error can name the file, the line and the key.

Both the model file and the daemon configuration go through :class:`Section`:
each value is taken with its expected kind, unknown keys are refused, and an
error reads ``config/model.yaml:14: transfer_functions.ptc_to_flange.denominator:
...``.

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
from pathlib import Path
from typing import Any, Iterable

import yaml

_FLOAT_PATTERN = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


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
    """

    def __init__(self, source: str, line: int | None, key: str, reason: str):
        self.source = source
        self.line = line
        self.key = key
        self.reason = reason
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {key + ': ' if key else ''}{reason}")


class _LocatedDict(dict):
    """A dict that remembers the line of itself and of each key (1-based)."""

    line: int = 0
    key_lines: dict


class _LocatingLoader(yaml.SafeLoader):
    """SafeLoader that records line numbers and refuses duplicate keys."""


def _construct_mapping(loader: _LocatingLoader, node: yaml.MappingNode) -> _LocatedDict:
    loader.flatten_mapping(node)
    mapping = _LocatedDict()
    mapping.line = node.start_mark.line + 1
    mapping.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in mapping:
            raise FileFormatError(
                loader.name, key_node.start_mark.line + 1, str(key), "key given twice"
            )
        mapping[key] = loader.construct_object(value_node, deep=True)
        mapping.key_lines[key] = key_node.start_mark.line + 1
    return mapping


_LocatingLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping
)


def _parse(text: str, source: str) -> Any:
    loader = _LocatingLoader(text)
    loader.name = source
    try:
        return loader.get_single_data()
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        line = mark.line + 1 if mark is not None else None
        raise FileFormatError(source, line, "", f"not valid YAML: {error.problem}") from None
    except yaml.YAMLError as error:
        raise FileFormatError(source, None, "", f"not valid YAML: {error}") from None
    finally:
        loader.dispose()


_MISSING = object()


def read_text_file(path: str | Path) -> str:
    """The text of a UTF-8 file; a missing or unreadable file is a :class:`FileFormatError`."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileFormatError(str(path), None, "", "file not found") from None
    except (OSError, UnicodeDecodeError) as error:
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

    def line_of(self, key: str | None = None) -> int | None:
        if key is not None and key in getattr(self.data, "key_lines", {}):
            return self.data.key_lines[key]
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
    def number(self, key: str, default: Any = _MISSING, *, minimum: float | None = None,
               maximum: float | None = None, exclusive_minimum: bool = False,
               integer: bool = False) -> float:
        """A finite number (int or float; '20e-6' style strings accepted)."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        number = self._as_number(key, value)
        if integer and number != int(number):
            raise self.error(key, f"must be a whole number, got {value!r}")
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
            raise self.error(key, f"must be a number, got {value!r}")
        if isinstance(value, str) and _FLOAT_PATTERN.match(value.strip()):
            value = float(value)
        if not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {type(value).__name__} {value!r}")
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value!r}")
        return float(value)

    def numbers(self, key: str, default: Any = _MISSING, *, min_length: int = 1) -> list[float]:
        """A list of finite numbers."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list):
            raise self.error(key, f"must be a list of numbers, got {value!r}")
        if len(value) < min_length:
            raise self.error(key, f"needs at least {min_length} number(s)")
        return [self._as_number(key, item) for item in value]

    def text(self, key: str, default: Any = _MISSING, *, choices: Iterable[str] | None = None) -> str:
        """A string, optionally one of ``choices``."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be text, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(sorted(choices))}; got {value!r}")
        return value

    def flag(self, key: str, default: Any = _MISSING) -> bool:
        """A boolean (true/false)."""
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def file_mode(self, key: str, default: Any = _MISSING) -> int:
        """A Unix file mode written in octal, e.g. "0660" (quoted or not)."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if isinstance(value, bool):
            raise self.error(key, f"must be an octal file mode like \"0660\", got {value!r}")
        if isinstance(value, int):
            mode = value            # YAML 1.1 reads an unquoted 0660 as octal already
        else:
            try:
                mode = int(str(value), 8)
            except ValueError:
                raise self.error(key, f"must be an octal file mode like \"0660\", got {value!r}") from None
        if not 0 <= mode <= 0o777:
            raise self.error(key, f"must be between 0000 and 0777, got {value!r}")
        return mode

    def section(self, key: str, default: Any = _MISSING) -> "Section | None":
        """A nested mapping; ``default=None`` makes it optional."""
        value = self._get(key, default)
        if value is None and default is None:
            return None
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping of keys to values, got {value!r}")
        return Section(value, self.source, self.key_path(key), self.line_of(key))

    def sections(self, key: str, default: Any = _MISSING) -> list["Section"]:
        """A list of mappings."""
        value = self._get(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, got {value!r}")
        result = []
        for index, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.error(key, f"item {index} must be a mapping, got {item!r}")
            result.append(Section(item, self.source, f"{self.key_path(key)}[{index}]",
                                  getattr(item, "line", None)))
        return result

    def finish(self) -> None:
        """Refuse keys that were never asked for (typos, unsupported options)."""
        unknown = [key for key in self.data if key not in self._taken]
        if unknown:
            key = unknown[0]
            known = ", ".join(sorted(str(k) for k in self._taken)) or "none"
            raise self.error(str(key), f"unknown key (known keys here: {known})")
