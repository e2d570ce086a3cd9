"""The token a write from the web page must carry, read from ``web.token_file``.

The file belongs to the service and its group (``chown cryod:cryod``, mode 0640 or 0600): whoever
may read it may control the daemon from the page, as whoever is in the socket's group may use
``cryod ctl``. A file that others may read, that is empty, or whose token is shorter than
:data:`MIN_TOKEN_LENGTH` characters is refused with the reason.
"""

from __future__ import annotations

import hmac
import os
import stat
from pathlib import Path

#: Shortest token taken (characters): ``openssl rand -hex 32`` gives 64.
MIN_TOKEN_LENGTH = 16
#: Longest token file read (bytes).
MAX_TOKEN_FILE_BYTES = 4096


def read_token(path: Path) -> str:
    """The token in ``path`` (its first line, without surrounding spaces).

    Raises
    ------
    ValueError
        The file can be read by others, cannot be read, is too large, or holds no usable token.
    """
    path = Path(path)
    try:
        info = os.stat(path)
        if stat.S_IMODE(info.st_mode) & 0o007:
            raise ValueError(f"{path} has mode {stat.S_IMODE(info.st_mode):04o}: every user of this computer "
                             f"could read the token and control the daemon; give owner and group only "
                             f"(chmod 0640)")
        if info.st_size > MAX_TOKEN_FILE_BYTES:
            raise ValueError(f"{path} is {info.st_size} bytes: a token file holds one line")
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ValueError(f"{path} cannot be read: {error.strerror or error}") from None
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
