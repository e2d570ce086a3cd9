"""Files the tools write: never over their input, never over a file they did not write.

``cryod analyze``, ``cryod identify`` and ``cryod plot`` check every file they
are about to write before any work starts:

* a file they read (the record, the model) is never written, even with
  ``--force`` (compared with :func:`os.path.samefile`, so a link or another
  spelling of the path is caught too);
* something that is not a regular file (a directory, a FIFO, a device) is not
  written over;
* without ``--force`` no existing file is replaced;
* with ``--force`` a file the user named (``--out FILE``) is replaced; in an
  output directory (``cryod analyze --out DIR``, ``cryod identify --report DIR``),
  whose file names the tool chooses, only files cryod wrote there itself are:
  each directory keeps the list of what cryod wrote into it, with each file's
  size and SHA-256 (:data:`MANIFEST_NAME`), so a file put there by someone else,
  or changed since, is left alone.

Examples
--------
>>> import shutil, tempfile
>>> folder = Path(tempfile.mkdtemp())
>>> outputs = OutputFiles("cryod analyze", folder, ["report.md"], what="analysis")
>>> outputs.refusal(force=False) is None
True
>>> _ = (folder / "report.md").write_text("the analysis")
>>> outputs.note_written()
>>> outputs.refusal(force=False).endswith("holds an earlier analysis (report.md); give --force to replace it")
True
>>> outputs.refusal(force=True) is None
True
>>> _ = (folder / "report.md").write_text("notes of my own")
>>> "cryod did not write it" in outputs.refusal(force=True)
True
>>> shutil.rmtree(folder)
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path
from typing import Iterable

from cryod.regular_files import open_regular_file

#: The list of files cryod wrote into a directory, with their sizes and SHA-256.
MANIFEST_NAME = ".cryod-written.json"
#: A manifest larger than this is not one of cryod's.
_MANIFEST_MAX_BYTES = 1 << 20


def _digest(path: Path) -> str:
    with open_regular_file(path) as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()


def _same_file(path: Path, others: Iterable[Path]) -> Path | None:
    """The first of ``others`` that is the same file as ``path`` (both existing)."""
    for other in others:
        try:
            if os.path.samefile(path, other):
                return Path(other)
        except (OSError, ValueError):
            continue
    return None


def _not_regular(path: Path) -> str | None:
    """What ``path`` is when it exists and is not a regular file."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as error:
        return f"cannot be looked at ({error.strerror or error})"
    if stat.S_ISREG(mode):
        return None
    return "is a directory" if stat.S_ISDIR(mode) else "is not a regular file (a FIFO, a device or a socket)"


def _input_refusal(tool: str, path: Path, inputs: Iterable[Path]) -> str | None:
    read = _same_file(path, inputs)
    if read is not None:
        same = "" if Path(read) == path else f" ({read})"
        return (f"{path} is a file {tool} reads{same}: it never writes over its input, even with --force; "
                f"write somewhere else")
    return None


def output_file_refusal(tool: str, path: str | os.PathLike, *, force: bool, inputs: Iterable = ()) -> str | None:
    """Why ``tool`` may not write the file the user named, or None when it may.

    Parameters
    ----------
    tool : str
        ``"cryod plot"``, ...: named in the message.
    path : path-like
        The file to write (the user named it: ``--force`` replaces it).
    force : bool
        ``--force`` was given.
    inputs : iterable of path-like
        The files the tool reads: never written.

    Returns
    -------
    str or None
    """
    path = Path(path)
    refusal = _input_refusal(tool, path, [Path(item) for item in inputs])
    if refusal is not None:
        return refusal
    what = _not_regular(path)
    if what is not None:
        return f"{path} {what}: {tool} writes a file there only in place of a regular file"
    if path.exists() and not force:
        return f"{path} exists; give --force to replace it"
    return None


class OutputFiles:
    """The files one run of a tool writes into a directory, checked before and listed after.

    Parameters
    ----------
    tool : str
        ``"cryod analyze"``, ``"cryod identify"``: named in the messages.
    directory : path-like
    names : iterable of str
        Every file the run may write there (a file name each).
    inputs : iterable of path-like
        The files the tool reads: never written.
    what : str
        What the files make up, for the message about an earlier run (``"analysis"``, ``"report"``).
    """

    def __init__(self, tool: str, directory: str | os.PathLike, names: Iterable[str], *, inputs: Iterable = (),
                 what: str = "output"):
        self.tool = tool
        self.directory = Path(directory)
        self.names = list(dict.fromkeys(names))
        self.inputs = [Path(item) for item in inputs]
        self.what = what

    @property
    def manifest_path(self) -> Path:
        return self.directory / MANIFEST_NAME

    def _manifest(self) -> dict | None:
        """The directory's list of what cryod wrote ({} when there is none; None when a file of that name is
        not one)."""
        path = self.manifest_path
        if not path.exists():
            return {}
        try:
            with open_regular_file(path) as stream:
                text = stream.read(_MANIFEST_MAX_BYTES + 1)
            manifest = json.loads(text.decode("utf-8")) if len(text) <= _MANIFEST_MAX_BYTES else None
        except (OSError, ValueError):
            return None
        files = manifest.get("files") if isinstance(manifest, dict) else None
        if not isinstance(files, dict) or not all(isinstance(entry, dict) for entry in files.values()):
            return None
        return files

    def _written_by_cryod(self, name: str, manifest: dict) -> bool:
        entry = manifest.get(name)
        path = self.directory / name
        try:
            return (entry is not None and entry.get("bytes") == path.stat().st_size
                    and entry.get("sha256") == _digest(path))
        except (OSError, ValueError):
            return False

    def refusal(self, force: bool) -> str | None:
        """Why the run may not write its files, or None when it may.

        Parameters
        ----------
        force : bool
            ``--force`` was given: replace cryod's own earlier files.
        """
        if self.directory.exists() and not self.directory.is_dir():
            return f"{self.directory} is not a directory"
        manifest = self._manifest()
        if manifest is None:
            return (f"{self.manifest_path} is not the list of files cryod wrote there; move it, or choose "
                    f"another directory")
        earlier = []
        for name in [*self.names, MANIFEST_NAME]:
            path = self.directory / name
            refusal = _input_refusal(self.tool, path, self.inputs)
            if refusal is not None:
                return refusal
            what = _not_regular(path)
            if what is not None:
                return f"{path} {what}; {self.tool} would write a file of that name there: choose another directory"
            if name == MANIFEST_NAME or not path.exists():
                continue
            if not self._written_by_cryod(name, manifest):
                how = (f"{self.tool} replaces only the files cryod wrote itself, even with --force"
                       if force else "it is kept")
                return (f"{path} is in the way: cryod did not write it (or it changed since), and {how}; move it, "
                        f"or choose another directory")
            earlier.append(name)
        if earlier and not force:
            return f"{self.directory} holds an earlier {self.what} ({earlier[0]}); give --force to replace it"
        return None

    def note_written(self) -> str | None:
        """Add the run's files that exist now to the directory's list of what cryod wrote (written to a
        temporary name, then renamed); returns a warning when the list could not be written (a later
        ``--force`` then keeps those files)."""
        manifest = self._manifest() or {}
        temporary = self.manifest_path.with_name(MANIFEST_NAME + ".partial")
        try:
            for name in self.names:
                path = self.directory / name
                if path.is_file():
                    manifest[name] = {"bytes": path.stat().st_size, "sha256": _digest(path), "tool": self.tool}
            temporary.write_text(json.dumps({"files": manifest}, indent=1, sort_keys=True) + "\n",
                                 encoding="utf-8")
            os.replace(temporary, self.manifest_path)
        except (OSError, ValueError) as error:
            temporary.unlink(missing_ok=True)
            return f"the list of the files written could not be saved as {self.manifest_path}: {error}"
        return None


__all__ = ["MANIFEST_NAME", "OutputFiles", "output_file_refusal"]
