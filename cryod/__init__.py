"""cryod: temperature regulation of a pulse-tube cooled cryostat flange."""

__version__ = "0.1.0"
