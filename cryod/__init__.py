"""cryod: temperature regulation of a pulse-tube cooled cryostat flange.

The public Python API, for notebooks and experiment scripts (docs/how-to/scripts.md):

* :func:`connect`, :class:`DaemonClient`: status and commands of a running daemon
  (``setpoint``, ``ramp``, ``heater_off``, ``manual``, ``feedforward``,
  ``wait_until_stable``); refusals raise :class:`CommandRefused`.
* :func:`read_record`: a cryod-log v1 file as numpy columns (:class:`Record`);
  :func:`record_frame`: the same as a pandas DataFrame.
* :func:`load_model`: a cryostat model file (the shipped one by default).
* :func:`simulate`: the daemon on the simulated cryostat, returning its summary
  and record paths (:class:`SimulationRun`).

Names are imported when first used, so ``import cryod`` stays light.
"""

__version__ = "0.1.0"

#: Public name -> module that defines it.
_API = {
    "connect": "cryod.client",
    "DaemonClient": "cryod.client",
    "CommandRefused": "cryod.client",
    "NotStable": "cryod.client",
    "read_record": "cryod.records.record",
    "Record": "cryod.records.record",
    "RecordFormatError": "cryod.records.record",
    "record_frame": "cryod.records.dataframe",
    "load_model": "cryod.model",
    "CryostatModel": "cryod.model",
    "simulate": "cryod.service.simulation",
    "SimulationRun": "cryod.service.simulation",
    "SimulationNotStarted": "cryod.service.simulation",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'cryod' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
