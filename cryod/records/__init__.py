"""Data records: the cryod-log v1 columns, reading and writing records, the data log, regulation metrics."""
