"""Bounded fuzzing of the configuration loader: a usable configuration or a FileFormatError, nothing else.

Random YAML documents, random text, and mutations of the example configuration
(lines dropped, doubled, swapped, re-indented; values replaced by hostile tokens or
random numbers and text). Whatever the file holds, :func:`cryod.config.load_config`
returns a :class:`~cryod.config.DaemonConfig` or raises the project's
:class:`~cryod.yaml_source.FileFormatError` with a short message: never another
exception, and never a message that quotes the file at length.
"""

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cryod.config import DaemonConfig, load_config
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG

pytestmark = pytest.mark.slow

EXAMPLE_LINES = [line for line in (CONFIG / "cryod.yaml").read_text().replace(
    "calibration: calibration/", f"calibration: {CONFIG}/calibration/").splitlines()
    if line.strip() and not line.lstrip().startswith("#")]
#: Longest message an error may have (a file name of a few hundred characters and a bounded reason).
MESSAGE_CHARS = 2000

FUZZ = settings(max_examples=250, deadline=2000, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

HOSTILE_TOKENS = [
    "", "~", "null", "''", '""', "[", "]", "{", "}", "[]", "{}", "- a", "? [a, b]", "[a, b]: 1", "{a: 1}: 2",
    "&a", "*a", "&a [1, *a]", "*undefined", "<<: 5", "<<: *a", "!!python/object/apply:os.system [ls]",
    "!!binary '!!'", "!!float x", "!!int 1.5", "!!set {a, b}", "!!omap [a]", "!!timestamp 2024-02-30",
    "2024-13-45", "9" * 400, "-" + "9" * 5000, "1e999", "-1e999", ".nan", ".inf", "-.inf", "0x1F", "0o777",
    "0777", '"0777"', '"0666"', "1_000", "yes", "no", "on", "true", "False", "-0", "1e-400", "0", "-1",
    '"\\0"', '"~nobody-here/x"', "/", "/dev/null", "/dev/zero", ".", "..", "\t1", "'unterminated",
    "\"\\x\"", "|\n  block", ">\n  folded", "%YAML 1.1", "---", "...", "#", "a: b: c", "é", "\u202e",
    str(CONFIG), str(CONFIG / "model.yaml"), str(CONFIG / "calibration"),
]


def check_load(tmp_path, text: str) -> None:
    path = tmp_path / "cryod.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        config = load_config(path)
    except FileFormatError as error:
        assert len(str(error)) < MESSAGE_CHARS, str(error)[:500]
        assert error.source == str(path)
    else:
        assert isinstance(config, DaemonConfig)


# --- random YAML documents, and random subtrees of the example ----------------------------------
EXAMPLE_DOCUMENT = yaml.safe_load("\n".join(EXAMPLE_LINES))
scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=20),
                    st.sampled_from([10 ** 400, -(10 ** 400), "0660", "0777", "", "cryod-config v1"]))
keys = st.one_of(st.text(max_size=12), st.integers(), st.booleans(),
                 st.tuples(st.integers(), st.text(max_size=3)))          # a tuple is written as a list key
documents = st.recursive(
    scalars,
    lambda children: st.one_of(st.lists(children, max_size=5), st.dictionaries(keys, children, max_size=5)),
    max_leaves=40)


def paths_of(document, prefix=()):
    """Every key path of a nested mapping, outermost first."""
    for key, value in document.items():
        yield prefix + (key,)
        if isinstance(value, dict):
            yield from paths_of(value, prefix + (key,))


EXAMPLE_PATHS = list(paths_of(EXAMPLE_DOCUMENT))


def replaced(document, path, value):
    copy = dict(document)
    copy[path[0]] = value if len(path) == 1 else replaced(copy[path[0]], path[1:], value)
    return copy


@FUZZ
@given(document=documents)
def test_random_yaml_documents(tmp_path, document):
    if isinstance(document, dict):
        document = {"format": "cryod-config v1", **document}
    check_load(tmp_path, yaml.safe_dump(document, allow_unicode=True))


@FUZZ
@given(path=st.sampled_from(EXAMPLE_PATHS), value=documents)
def test_random_values_in_the_example_configuration(tmp_path, path, value):
    check_load(tmp_path, yaml.safe_dump(replaced(EXAMPLE_DOCUMENT, path, value), allow_unicode=True))


@FUZZ
@given(text=st.text(max_size=400))
def test_random_text(tmp_path, text):
    check_load(tmp_path, text)


# --- mutations of the example configuration ---------------------------------------------------
def replace_value(line: str, value: str) -> str:
    key, colon, _ = line.partition(":")
    return f"{key}: {value}" if colon else value


values = st.one_of(st.sampled_from(HOSTILE_TOKENS), st.sampled_from(HOSTILE_TOKENS),
                   st.floats().map(repr), st.integers().map(str),
                   st.text(max_size=30).map(lambda text: yaml.safe_dump(text, allow_unicode=True).splitlines()[0]))
#: Lines inserted where a key may stand: hostile keys, and keys with hostile values.
inserted = st.one_of(st.sampled_from(HOSTILE_TOKENS),
                     st.tuples(st.sampled_from(["[a, b]", "{a: 1}", "? [a]\n", "<<", "period_s", "mode", "*a",
                                                "&a key", "!!binary a", "1", "null"]), values)
                     .map(lambda pair: f"{pair[0]}: {pair[1]}"))
mutations = st.one_of(
    st.tuples(st.just("replace"), st.integers(0, len(EXAMPLE_LINES) - 1), values),
    st.tuples(st.just("drop"), st.integers(0, len(EXAMPLE_LINES) - 1), st.just("")),
    st.tuples(st.just("double"), st.integers(0, len(EXAMPLE_LINES) - 1), st.just("")),
    st.tuples(st.just("swap"), st.integers(0, len(EXAMPLE_LINES) - 1), st.integers(0, len(EXAMPLE_LINES) - 1)),
    st.tuples(st.just("indent"), st.integers(0, len(EXAMPLE_LINES) - 1), st.sampled_from(["", " ", "    ", "\t"])),
    st.tuples(st.just("insert"), st.integers(0, len(EXAMPLE_LINES)), inserted),
)


def mutated(changes) -> str:
    lines = list(EXAMPLE_LINES)
    for kind, where, what in changes:
        where = min(where, len(lines) - 1) if lines else 0
        if not lines:
            lines.append(str(what))
        elif kind == "replace":
            lines[where] = replace_value(lines[where], what)
        elif kind == "drop":
            del lines[where]
        elif kind == "double":
            lines.insert(where, lines[where])
        elif kind == "swap":
            other = min(what, len(lines) - 1)
            lines[where], lines[other] = lines[other], lines[where]
        elif kind == "indent":
            lines[where] = what + lines[where].lstrip()
        else:                   # insert, indented as the line it goes before
            neighbour = lines[where]
            lines.insert(where, neighbour[:len(neighbour) - len(neighbour.lstrip())] + what)
    return "\n".join(lines) + "\n"


@FUZZ
@given(changes=st.lists(mutations, min_size=1, max_size=4))
def test_mutations_of_the_example_configuration(tmp_path, changes):
    check_load(tmp_path, mutated(changes))


@FUZZ
@given(line=st.sampled_from([index for index, line in enumerate(EXAMPLE_LINES)
                             if ":" in line and not line.lstrip().startswith("#")]),
       number=st.one_of(st.floats(), st.integers(min_value=-10 ** 500, max_value=10 ** 500)))
def test_any_number_in_any_value(tmp_path, line, number):
    """Every value of the example replaced by any number: the limits' cross-checks never fail another way."""
    lines = list(EXAMPLE_LINES)
    lines[line] = replace_value(lines[line], repr(number) if isinstance(number, float) else str(number))
    check_load(tmp_path, "\n".join(lines) + "\n")
