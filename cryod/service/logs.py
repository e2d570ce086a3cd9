"""Logging for the service: journald priority prefixes, and no I/O in the loop thread.

Every line on stderr starts with ``<N>`` (sd-daemon priority: 2 critical,
3 error, 4 warning, 6 info, 7 debug) when stderr goes to the journal
(systemd sets ``JOURNAL_STREAM``); anywhere else (a terminal, a pipe, a file)
a warning or worse says its level in words after the logger's name
(``cryod.loop: warning: ...``). Records pass through a queue, so a log call in
the loop thread never waits on a stream.
"""

from __future__ import annotations

import logging
import logging.handlers
import os
import queue
import sys

PRIORITIES = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6, logging.DEBUG: 7}


class JournalFormatter(logging.Formatter):
    """``<priority>logger: message`` for the journal (continuation lines prefixed too); without the
    prefix, ``logger: level: message`` for warnings and worse, ``logger: message`` below."""

    def __init__(self, prefix: bool):
        super().__init__("%(name)s: %(message)s")
        self.prefix = prefix

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if not self.prefix:
            if record.levelno >= logging.WARNING:
                return f"{record.name}: {record.levelname.lower()}: {text[len(record.name) + 2:]}"
            return text
        priority = PRIORITIES.get(record.levelno, 6 if record.levelno < logging.WARNING else 3)
        return "\n".join(f"<{priority}>{line}" for line in text.splitlines())


def wants_prefix() -> bool:
    """Prefix when stderr goes to the journal (systemd sets ``JOURNAL_STREAM`` for a service)."""
    return "JOURNAL_STREAM" in os.environ


def reply_for_log(text: str) -> str:
    """A command's reply as the log writes it: whole for the journal; elsewhere (a dry run's terminal, where
    the log shares the screen with the status line) its first line, saying how many more the client got."""
    lines = text.splitlines()
    if len(lines) <= 1 or wants_prefix():
        return text
    return f"{lines[0]} (and {len(lines) - 1} more lines, in the reply)"


class ServiceLogging:
    """Queue-based logging to stderr for the life of the daemon.

    Parameters
    ----------
    level : int
        Lowest level written.
    stream : file object, optional
        Where lines go (default stderr).
    """

    def __init__(self, level: int = logging.INFO, stream=None):
        self.stream = stream or sys.stderr
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        handler = logging.StreamHandler(self.stream)
        handler.setFormatter(JournalFormatter(wants_prefix()))
        self._listener = logging.handlers.QueueListener(self._queue, handler)
        self._queue_handler = logging.handlers.QueueHandler(self._queue)
        self.level = level
        self._logger = logging.getLogger("cryod")
        self._running = False

    def start(self) -> None:
        self._logger.addHandler(self._queue_handler)
        self._logger.setLevel(self.level)
        self._logger.propagate = False
        self._listener.start()
        self._running = True

    def stop(self) -> None:
        """Write what is queued and detach; a second call does nothing."""
        if not self._running:
            return
        self._running = False
        self._listener.stop()
        self._logger.removeHandler(self._queue_handler)
        self._logger.propagate = True
