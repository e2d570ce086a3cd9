"""The feedforward's settings: the ``control.feedforward`` section of the daemon's configuration.

Optional; it reloads with SIGHUP, bumplessly (keeping the lock, the learned plant and the learned
waveform). Its keys, with their defaults::

    feedforward:
      enabled: true              # cryod ctl feedforward on|off switches it without a reload
      harmonics: 6
      update_interval_s: 2.0     # the waveform steps this often
      memory_s: 60.0             # the line estimate may drift over this
      learning_gain: 0.5         # fraction of the way to the estimated best waveform per step
      fade_time_s: 5.0
      margin_W: 0.001            # kept from 0 W and from R I_max^2
      minimum_cooler_amplitude_K: 0.01
      probe_amplitude_K: 1.0e-4  # T2's answer to the probe at each harmonic probed (0: no probe)
      plant_precision: 0.03      # the probe stops at a harmonic once its plant is known this well (relative)
      retry_after_s: 120.0       # after a divergence, learning starts again this much later
      model: null                # the controller's model (null: the shipped model)

Examples
--------
>>> settings = FeedforwardSettings()
>>> settings.harmonics, settings.fade_time_s, settings.retry_after_s
(6, 5.0, 120.0)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cryod.control.feedforward.divergence_retry import LONGEST_RETRY_S
from cryod.control.feedforward.plant_probe import ProbeSettings
from cryod.control.feedforward.synchronous_estimator import DEFAULT_PERIOD_S
from cryod.model import DEFAULT_MODEL_PATH, CryostatModel, load_model
from cryod.yaml_source import FileFormatError, Section


@dataclass(frozen=True)
class FeedforwardSettings:
    """The ``control.feedforward`` section.

    Attributes
    ----------
    enabled : bool
        On at start (``cryod ctl feedforward on|off`` switches it while running).
    harmonics : int
        Harmonics of the cooler frequency in the waveform and the residual.
    update_interval_s : float
        The waveform steps this often (s).
    memory_s : float
        Memory of the estimate of T2's synchronous part (s).
    learning_gain : float
        Fraction of the way to the estimated best waveform taken per step (0 to 1).
    fade_time_s : float
        Fade in and out (s).
    margin_W : float
        Distance kept from 0 W and from R I_max^2 (W).
    minimum_cooler_amplitude_K : float
        T5 oscillation below this counts as no cooler signal (K).
    probe_amplitude_K : float
        T2's answer to the probe at each harmonic probed (K; 0: no probe).
    plant_precision : float
        The probe stops at a harmonic once its plant is known this well (relative standard deviation).
    retry_after_s : float
        After a divergence, learning starts again this much later (s; doubling for each in a row).
    model : CryostatModel
        The controller's model (plant response at each harmonic).
    model_source : str
        Where the model came from.
    period_s : float
        Loop period (s): the hold of each heater setting.
    """

    enabled: bool = True
    harmonics: int = 6
    update_interval_s: float = 2.0
    memory_s: float = 60.0
    learning_gain: float = 0.5
    fade_time_s: float = 5.0
    margin_W: float = 0.001
    minimum_cooler_amplitude_K: float = 0.01
    probe_amplitude_K: float = 100e-6
    plant_precision: float = 0.03
    retry_after_s: float = 120.0
    model: CryostatModel | None = None
    model_source: str = "shipped model"
    period_s: float = DEFAULT_PERIOD_S

    @property
    def controller_model(self) -> CryostatModel:
        return self.model if self.model is not None else load_model(DEFAULT_MODEL_PATH)

    @property
    def probe(self) -> ProbeSettings:
        return ProbeSettings(amplitude_K=self.probe_amplitude_K, precision=self.plant_precision,
                             noise_K=self.controller_model.sensor_noise.flange_thermometer_rms_K,
                             readings_per_s=1.0 / self.period_s)


def settings_from(section: Section | None) -> FeedforwardSettings:
    """The ``control.feedforward`` section, validated (defaults when it is absent).

    Parameters
    ----------
    section : Section or None
        The section as the configuration file has it (None: absent).

    Returns
    -------
    FeedforwardSettings

    Raises
    ------
    FileFormatError
        A key out of its range, one the section does not know, or a controller's model that cannot be read
        (the error names the file, the line and the key).
    """
    if section is None:
        return FeedforwardSettings(model=load_model(DEFAULT_MODEL_PATH))
    defaults = FeedforwardSettings()
    model_path = section.text("model", None)
    try:
        model = load_model(_resolve(model_path, section.source)) if model_path else load_model(DEFAULT_MODEL_PATH)
    except FileFormatError as error:
        raise section.error("model", f"controller model not usable: {error}") from None
    settings = FeedforwardSettings(
        enabled=section.flag("enabled", defaults.enabled),
        harmonics=section.number("harmonics", defaults.harmonics, minimum=1, maximum=12, integer=True),
        update_interval_s=section.number("update_interval_s", defaults.update_interval_s, minimum=0.5,
                                         maximum=60.0),
        memory_s=section.number("memory_s", defaults.memory_s, minimum=2.0, maximum=3600.0),
        learning_gain=section.number("learning_gain", defaults.learning_gain, minimum=0.0,
                                     exclusive_minimum=True, maximum=1.0),
        fade_time_s=section.number("fade_time_s", defaults.fade_time_s, minimum=0.0, maximum=600.0),
        margin_W=section.number("margin_W", defaults.margin_W, minimum=0.0, maximum=1.0),
        minimum_cooler_amplitude_K=section.number("minimum_cooler_amplitude_K",
                                                  defaults.minimum_cooler_amplitude_K, minimum=0.0,
                                                  exclusive_minimum=True),
        probe_amplitude_K=section.number("probe_amplitude_K", defaults.probe_amplitude_K, minimum=0.0,
                                         maximum=1e-3),
        plant_precision=section.number("plant_precision", defaults.plant_precision, minimum=0.001,
                                       maximum=0.2),
        retry_after_s=section.number("retry_after_s", defaults.retry_after_s, minimum=10.0,
                                     maximum=LONGEST_RETRY_S),
        model=model, model_source=model_path or "shipped model")
    section.finish()
    return settings


def _resolve(path: str, config_source: str) -> Path:
    """A model file's path as written in the configuration: relative to the configuration file's folder."""
    candidate = Path(path).expanduser()
    if not candidate.is_absolute() and config_source and not config_source.startswith("<"):
        candidate = Path(config_source).resolve().parent / candidate
    return candidate


__all__ = ["FeedforwardSettings", "settings_from"]
