"""The operator's notes: ``cryod ctl note TEXT`` written into the record being written and the journal.

A note is the daemon's, not the loop's: it is written at once, whether or not
the loop runs, as ``# event: note: TEXT (by WHO)`` in the record (who sent it
as the control socket saw it: uid, user name, pid), into the live stream (the
web page's events) and at info level in the journal.
"""

from __future__ import annotations

import logging

from cryod.records.columns import Event

log = logging.getLogger("cryod.notes")


def write_note(put, text: str, sender: str) -> str:
    """Write a note into the record (through ``put``, the data log's queue) and the journal; the reply.

    Parameters
    ----------
    put : callable
        Takes an :class:`~cryod.records.columns.Event` for the record and the stream.
    text : str
        The note, already checked (:func:`cryod.service.commands.note_text`).
    sender : str
        Who sent it (empty: unknown).

    Returns
    -------
    str
        The reply to the sender.
    """
    by = f" (by {sender})" if sender else ""
    put(Event("note", f"{text}{by}"))
    log.info("note: %s%s", text, by)
    return f"note written: {text}"
