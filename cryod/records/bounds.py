"""The most a record may hold, so that a damaged or hostile file is refused in bounded memory and time.

Each bound is far above anything the daemon writes: a day's file has about
1.08 million rows (12.5 a second) and a 7-day record about 7.6 million; a row
with the feedforward's 24 columns is about 225 characters, the longest header
line (``units``) about 1 800 and the whole header about 9 kB. The readers
(:func:`cryod.read_record`, ``cryod analyze``, ``cryod identify``, ``cryod plot``)
enforce them while the file streams in, a line at a time with its length
limited as it is read, and refuse the file with its name, the line and the
bound. What fits inside the bounds takes at most: a header of
:data:`MAX_HEADER_CHARACTERS`, one chunk of :data:`cryod.records.data_lines.CHUNK_ROWS`
lines of :data:`MAX_DATA_LINE_CHARACTERS` while it is split into fields,
:data:`MAX_EVENT_CHARACTERS` of events, and 8 bytes per number kept
(:data:`MAX_LINES` rows times the columns read).

Examples
--------
>>> MAX_LINES > 7 * 86400 / 0.08, MAX_DATA_LINE_CHARACTERS > 100 * 225
(True, True)
"""

#: Longest line of the header (magic line, metadata lines, column names), in characters.
MAX_HEADER_LINE_CHARACTERS = 1 << 20
#: All header lines together, in characters.
MAX_HEADER_CHARACTERS = 16 << 20
#: Most columns in the column header.
MAX_COLUMNS = 1000
#: Longest line after the header (a row or an event), in characters.
MAX_DATA_LINE_CHARACTERS = 64 << 10
#: Most lines in a record (header, rows, events and blank lines): 18.5 days of rows at 80 ms.
MAX_LINES = 20_000_000
#: Most text in a record, in characters (for a ``.csv.gz`` file: decompressed): 8 GiB.
MAX_TEXT_CHARACTERS = 8 << 30
#: Most event text (``# event: ...`` lines after the header) kept, in characters.
MAX_EVENT_CHARACTERS = 256 << 20

#: How a refusal ends: what the bounds are for.
NOT_A_RECORD = "a damaged file, or not a cryod record"


def size_text(characters: int) -> str:
    """A bound in characters as people read it (``64 KiB``, ``8 GiB``).

    >>> size_text(65536), size_text(8 << 30), size_text(1000)
    ('64 KiB', '8 GiB', '1000 characters')
    """
    for shift, unit in ((30, "GiB"), (20, "MiB"), (10, "KiB")):
        if characters >= 1 << shift and characters % (1 << shift) == 0:
            return f"{characters >> shift} {unit}"
    return f"{characters} characters"


__all__ = ["MAX_COLUMNS", "MAX_DATA_LINE_CHARACTERS", "MAX_EVENT_CHARACTERS", "MAX_HEADER_CHARACTERS",
           "MAX_HEADER_LINE_CHARACTERS", "MAX_LINES", "MAX_TEXT_CHARACTERS", "NOT_A_RECORD", "size_text"]
