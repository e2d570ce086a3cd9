"""How drivers reach instruments: PyVISA resources, Prologix adapters, simulated instruments in process.

See :mod:`drivers.transports.base` for the contract every transport keeps.
"""

from drivers.transports.base import Transport
from drivers.transports.in_process import InProcessTransport
from drivers.transports.prologix import PrologixAdapter, PrologixInstrument
from drivers.transports.visa import VisaTransport, resource_manager

__all__ = ["Transport", "InProcessTransport", "VisaTransport", "PrologixAdapter", "PrologixInstrument",
           "resource_manager"]
