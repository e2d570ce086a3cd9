"""The token a write from the web page must carry, read from ``web.token_file``.

The file belongs to the service and its group (``chown cryod:cryod``, mode 0640 or 0600): whoever
may read it may control the daemon from the page, as whoever is in the socket's group may use
``cryod ctl``. The file is read at start and again at every write, so a new token takes effect at
once; each time it is checked the same way: a regular file (a FIFO, a device or a directory put in
its place is refused before it is read, :func:`cryod.regular_files.open_regular_file`), owned by the
service's user or root, that others may not read, of at most :data:`MAX_TOKEN_FILE_BYTES` bytes (no
more is ever read), holding a token of at least :data:`MIN_TOKEN_LENGTH` characters. A file that fails
is refused with the reason.
"""

from __future__ import annotations

import hmac
import os
import stat
from pathlib import Path

from cryod.regular_files import NotARegularFile, open_regular_file

#: Shortest token taken (characters): ``openssl rand -hex 32`` gives 64.
MIN_TOKEN_LENGTH = 16
#: Longest token file read (bytes).
MAX_TOKEN_FILE_BYTES = 4096


def read_token(path: Path) -> str:
    """The token in ``path`` (its first line, without surrounding spaces).

    Raises
    ------
    ValueError
        Not a regular file, owned by another user, readable by others, cannot be read, too large, or
        holds no usable token.
    """
    path = Path(path)
    try:
        with open_regular_file(path) as opened:
            info = os.fstat(opened.fileno())
            if info.st_uid not in (os.geteuid(), 0):
                raise ValueError(f"{path} belongs to uid {info.st_uid}, not to this service's user (uid "
                                 f"{os.geteuid()}) or root: another user could change the token; chown it")
            if stat.S_IMODE(info.st_mode) & 0o007:
                raise ValueError(f"{path} has mode {stat.S_IMODE(info.st_mode):04o}: every user of this computer "
                                 f"could read the token and control the daemon; give owner and group only "
                                 f"(chmod 0640)")
            if info.st_size > MAX_TOKEN_FILE_BYTES:
                raise ValueError(f"{path} is {info.st_size} bytes: a token file holds one line")
            raw = opened.read(MAX_TOKEN_FILE_BYTES + 1)
    except NotARegularFile as error:
        raise ValueError(f"{path} {error.reason}: the token is read from a regular file only") from None
    except OSError as error:
        raise ValueError(f"{path} cannot be read: {error.strerror or error}") from None
    if len(raw) > MAX_TOKEN_FILE_BYTES:
        raise ValueError(f"{path} grew beyond {MAX_TOKEN_FILE_BYTES} bytes while it was read: a token file holds "
                         f"one line")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not UTF-8 text") from None
    lines = text.strip().splitlines()
    token = lines[0].strip() if lines else ""
    if len(token) < MIN_TOKEN_LENGTH or any(character.isspace() for character in token):
        raise ValueError(f"{path} holds no usable token: give one line of at least {MIN_TOKEN_LENGTH} characters "
                         f"without spaces (e.g. the output of `openssl rand -hex 32`)")
    return token


def token_matches(given: str | None, token: str) -> bool:
    """Whether ``given`` is ``token`` (compared in constant time)."""
    return given is not None and hmac.compare_digest(given.encode("utf-8", "replace"), token.encode("utf-8"))
