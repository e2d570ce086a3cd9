"""A record as a pandas DataFrame, for labs that analyse in pandas.

pandas is not a dependency of the daemon; this needs it installed, with
cryod's ``analysis`` extra (``pip install 'cryod[analysis]'``) or by itself. The frame has one column per record column, the
record's metadata in ``frame.attrs["metadata"]`` and its events (faults,
commands, reloads) in ``frame.attrs["events"]`` as (row index, text) pairs.
"""

from __future__ import annotations

from cryod.records.record import Record


def record_frame(record: Record):
    """The record's columns as a ``pandas.DataFrame`` (metadata and events in ``attrs``).

    Raises
    ------
    ImportError
        pandas is not installed; the message says how to get it.
    """
    try:
        import pandas
    except ImportError:
        raise ImportError("record_frame needs pandas: pip install 'cryod[analysis]' (or pandas by itself; "
                          "or use the record's numpy columns, record.columns)") from None
    frame = pandas.DataFrame(dict(record.columns))
    frame.attrs["metadata"] = dict(record.metadata)
    frame.attrs["events"] = list(record.events)
    frame.attrs["source"] = record.source
    return frame
