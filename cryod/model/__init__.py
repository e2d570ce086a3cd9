"""The cryostat model: one definition, loaded from YAML, used everywhere.

The simulator, the feedforward design and the analysis all read the model
through :func:`load_model` and compute its response with the same physics.
The equations behind every field are in ``docs/explanation/cryostat-model.md``.

Signal structure (deviations from the operating point, heater power P in W)::

    T2 = T2_0 + G2 * (G1 * P + G_link * q)      flange thermometer
    T5 = T5_0 + G3 * P + ptc_oscillation(t)      PTC second-stage thermometer
    q  = C * d(ptc_oscillation)/dt               PTC heat oscillation (paper eq. 4)

Modules:

* :mod:`~cryod.model.parameters`: what the model says (operating point,
  transfer functions, PTC source, effects, sensor noise);
* :mod:`~cryod.model.model_file`: reading and writing model files;
* :mod:`~cryod.model.transfer_function`: G(s), its frequency response and modal form;
* :mod:`~cryod.model.cooler_cycle`: the cooler's phase and frequency over time;
* :mod:`~cryod.model.heater_path`, :mod:`~cryod.model.cooler_path`: the two kinds of path;
* :mod:`~cryod.model.dynamics`: how they and the effects combine into T2 and T5;
* :mod:`~cryod.model.temperature_laws`, :mod:`~cryod.model.temperature_plant`: the cryostat
  across temperature (copper's heat capacity, the conductances' law, the cooler's line).

Examples
--------
>>> model = load_model(DEFAULT_MODEL_PATH)
>>> model.operating_point.flange_temperature_K
4.23
>>> round(model.heater_to_thermometer.dc_gain, 3)      # K/W
6.818
"""

from cryod.model.dynamics import CryostatPlant, SimulatedRecord, simulate
from cryod.model.model_file import (
    DEFAULT_MODEL_PATH, MODEL_FORMAT, TRANSFER_FUNCTION_UNITS, load_model, load_model_text, model_from_section,
    model_to_dict, save_model,
)
from cryod.model.parameters import (
    EFFECT_NAMES, GENERIC_EFFECT_NAMES, CryostatModel, DeadTime, Disturbance, Effects, HeatCapacityTemperature,
    HeaterNonlinearity, HeaterPathCorrection, LinkDynamics, OperatingPoint, Pickup, CoolerAmplitudeModulation,
    CoolerFrequencyDrift, CoolerHarmonic, CoolerSource, PtcStageDrift, SensorLag, SensorNoise, SlowProcess,
)
from cryod.model.cooler_cycle import CoolerCycle
from cryod.model.temperature_laws import TemperatureDependence
from cryod.model.temperature_plant import (
    TEMPERATURE_MODEL_PATH, TemperatureDependentPlant, cryostat_plant, linearised_at, steady_state,
)
from cryod.model.transfer_function import TransferFunction, TransferFunctionError
from cryod.yaml_source import FileFormatError

__all__ = [
    "CoolerAmplitudeModulation", "CoolerCycle", "CoolerFrequencyDrift", "CoolerHarmonic", "CoolerSource",
    "CryostatModel", "CryostatPlant", "DeadTime", "Disturbance", "Effects", "EFFECT_NAMES", "FileFormatError",
    "GENERIC_EFFECT_NAMES", "HeatCapacityTemperature", "HeaterNonlinearity", "HeaterPathCorrection", "LinkDynamics",
    "OperatingPoint", "Pickup", "PtcStageDrift", "SensorLag", "SensorNoise", "SimulatedRecord", "SlowProcess",
    "TemperatureDependence", "TemperatureDependentPlant", "TEMPERATURE_MODEL_PATH", "cryostat_plant",
    "linearised_at", "steady_state",
    "TransferFunction", "TransferFunctionError", "DEFAULT_MODEL_PATH", "MODEL_FORMAT", "TRANSFER_FUNCTION_UNITS",
    "load_model", "load_model_text", "model_from_section", "model_to_dict", "save_model", "simulate",
]
