"""The daemon configuration: one YAML file, validated before anything touches an instrument.

``config/cryod.yaml`` is the documented example (it runs with ``cryod --simulate``
as it is). Every error names the file, the line and the key. Relative paths
(calibration files, data directory, model) are taken relative to the
configuration file's folder.

The checks are written out section by section rather than declared to a schema library:
each says what a lab user must change, some span sections (the instruments' waits against
systemd's watchdog, two keys that name one instrument), and each control term reads its own
section (``settings_from``), so the section's rules live with the code that uses it.

Examples
--------
>>> config = load_config(EXAMPLE_CONFIG_PATH)
>>> config.loop.period_s, config.heater.max_current_A
(0.08, 0.1)
>>> round(config.heater.max_power_w, 3)      # R * I_max**2, as the supply driver takes it
0.5
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

from cryod.alarms.settings import AlarmsConfig, alarms_from_section
from cryod.control.ramp import MIN_RATE_K_PER_MIN, rate_refusal
from cryod.control.regulator import ControlConfig
from cryod.control.terms import term_settings_from
from cryod.control.zones import zone_table_from
from cryod.instrument_waits import InstrumentWaits
from cryod.listen_address import parse_address
from cryod.thermometry import CalibrationCurve, load_calibration
from cryod.web_token import read_token
from cryod.yaml_source import FileFormatError, Section, read_text_file, shown
from drivers.heater_limits import largest_power_w
from drivers.keithley2002_timing import ReadingTiming

CONFIG_FORMAT = "cryod-config v1"
EXAMPLE_CONFIG_PATH = Path(__file__).resolve().parent / "data" / "cryod.yaml"

TRIGGER_MODES = ("gpib-group", "prologix", "external", "sequential")
HEATER_MODELS = ("keithley6221", "keithley2400")
SIMULATION_TRANSPORTS = ("tcp", "in-process")
#: Time a cycle needs besides the readings: fetching, converting, the heater setting (s).
CYCLE_MARGIN_S = 0.015
#: Keys of the control section that moved into control.pi.
MOVED_TO_PI = ("proportional_W_per_K", "integral_W_per_K_s")
#: Fastest setpoint ramp a configuration may allow (K/min). Lake Shore controllers stop at the same
#: 100 K/min; a flange on a 4 K cooler follows a few K/min at most (the example's 0.5 W heater moves T2
#: by about 2 K/min through the model's 2.05 K/W fast path and 26.5 s thermometer lag), so a larger
#: figure is a slip (K/s for K/min, an exponent), not a wish.
MAX_RAMP_K_PER_MIN = 100.0
#: Permission bits for others (not owner, not group) on the control socket. Connecting to a Unix
#: socket needs write permission, and whoever connects can set the heater; read or execute bits
#: for others mean nothing on a socket but show a mode meant for a file, so all three are refused.
SOCKET_MODE_OTHERS = 0o007
#: Longest path a Unix socket can be bound to (bytes): the kernel's ``sun_path`` holds 108, the
#: terminating NUL included.
SOCKET_PATH_MAX_BYTES = 107
#: The instruments' keys under ``instruments``, with the names the drivers give them.
INSTRUMENT_KEYS = {"flange_dmm": "flange DMM (T2)", "ptc_stage_dmm": "PTC-stage DMM (T5)",
                   "heater_supply": "heater supply"}
#: Where every cryod on the host locks the instruments it drives (``instruments.lock_directory``): the
#: system's place for lock files, shared by all users and units; created at boot by systemd/cryod-tmpfiles.conf.
DEFAULT_LOCK_DIRECTORY = Path("/run/lock/cryod")


@dataclass(frozen=True)
class LoopConfig:
    period_s: float
    overrun_streak_limit: int
    realtime_priority: int
    lock_memory: bool


@dataclass(frozen=True)
class InstrumentAddress:
    """Where an instrument is: a VISA resource, or a Prologix adapter and GPIB address."""

    resource: str | None = None
    prologix_port: str | None = None       # serial device of a GPIB-USB adapter
    prologix_host: str | None = None       # host of a GPIB-ETHERNET adapter
    gpib_address: int | None = None


@dataclass(frozen=True)
class DmmSettings:
    """4-wire resistance settings shared by both Keithley 2002s."""

    range_ohm: float
    nplc: float
    digits: int
    filter_count: int
    autozero: bool
    autozero_synchronous: bool      # a zero with every reading: every reading's timing alike
    offset_compensation: bool
    line_sync: bool
    line_frequency_hz: float


@dataclass(frozen=True)
class TriggerOutputConfig:
    """The wire of an external hardware trigger: a serial port's control line to both DMMs."""

    port: str
    line: str
    dmm_input: str          # "external" (rear BNC inputs) or "trigger_link"
    link_line: int


@dataclass(frozen=True)
class InstrumentsConfig:
    trigger: str
    timeout_s: float
    visa_library: str
    flange_dmm: InstrumentAddress
    ptc_stage_dmm: InstrumentAddress
    heater_supply: InstrumentAddress
    heater_model: str
    dmm: DmmSettings
    trigger_output: TriggerOutputConfig | None = None
    #: Where this daemon locks each instrument's address against other cryod daemons on the host.
    lock_directory: Path = DEFAULT_LOCK_DIRECTORY


@dataclass(frozen=True)
class SensorsConfig:
    flange_calibration: Path
    ptc_stage_calibration: Path


@dataclass(frozen=True)
class HeaterConfig:
    resistance_ohm: float
    max_current_A: float
    voltage_compliance_V: float

    @property
    def max_power_w(self) -> float:
        """R * I_max**2 (W), rounded as the supply driver tests a power (:func:`drivers.heater_limits.largest_power_w`)."""
        return largest_power_w(self.resistance_ohm, self.max_current_A)


@dataclass(frozen=True)
class SafetyConfig:
    flange_max_K: float
    ptc_stage_max_K: float
    max_repeated_readings: int
    valid_readings_to_resume: int
    recovery_timeout_s: float
    instruments_wait_s: float | None = None     # None: wait for unreachable instruments without end
    #: The oldest readings the heater may be set from, and the longest a setting may outlive its readings when
    #: the loop does not run (s); beyond it the heater goes to 0 W (fault readings_too_old).
    max_reading_age_s: float = 0.5


@dataclass(frozen=True)
class DataConfig:
    directory: Path
    fsync_interval_s: float
    warn_free_MB: float = 1000.0        # below this free space: a warning in the journal and the record
    min_free_MB: float = 100.0          # below this: heater off, exit 7 (while the last rows still fit)
    compress_finished: bool = True      # records of finished UTC days become .csv.gz


@dataclass(frozen=True)
class SocketConfig:
    path: Path
    mode: int
    owner: str | None
    group: str | None


@dataclass(frozen=True)
class MetricsConfig:
    address: str | None = None          # host:port of the Prometheus endpoint; None: off
    cryostat: str = ""                  # the lab's name for this cryostat (label of cryod_info)


@dataclass(frozen=True)
class WebConfig:
    """The ``web`` section: the live page (off when the section is absent or null)."""

    address: str                        # host:port, 127.0.0.1 unless stated otherwise
    writable: bool = False              # control from the page (needs token_file)
    token_file: Path | None = None      # the token a write must carry; readable by the service's group only
    #: More names the ``Host`` header may give (a DNS name the lab reaches the PC by, a proxy's); the listening
    #: address, localhost and this computer's own names are always taken.
    allowed_hosts: tuple[str, ...] = ()


@dataclass(frozen=True)
class Lakeshore336Config:
    """The ``lakeshore336`` section: the Lake Shore 336 command set over TCP (off when absent or null)."""

    address: str                        # host:port, 127.0.0.1 unless stated otherwise
    writable: bool = False              # SETP, RAMP and RANGE taken (within the same limits as every path)
    #: Addresses of other computers whose writes are taken; from this computer, writes are taken from the users
    #: that may use the control socket.
    write_from: tuple[str, ...] = ()


#: The characters EPICS takes in a record name (a dot separates a record from its field, so it is not one).
PV_NAME_CHARACTERS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-+:[]<>;")
#: The longest ``ioc.prefix``: EPICS takes record names of up to 60 characters, and the IOC's names after
#: the prefix take up to 20 (cryod.ioc.pv_table checks its own).
MAX_PV_PREFIX = 40


@dataclass(frozen=True)
class IocConfig:
    """The ``ioc`` section: what ``cryod ioc`` serves to EPICS (off when the section is absent or null).

    The daemon does not read it: ``cryod ioc``, a process of its own, does (docs/how-to/epics-bluesky.md, "EPICS
    and Bluesky").
    """

    prefix: str                         # before every PV name: CRYO1: gives CRYO1:T2
    writable: bool = False              # puts reach the daemon (else every put is refused by access security)
    #: An EPICS access security file (ASG/UAG/HAG rules) the lab edits; None: cryod's own rules (reads for all,
    #: writes for all when writable).
    access_security_file: Path | None = None
    stable_tolerance_K: float = 1e-4    # STABLE: T2's 10 s average within this of the setpoint ...
    stable_hold_s: float = 60.0         # ... for this long (the daemon's clock), as wait_until_stable
    #: The longest a put with completion on SETPOINT waits for STABLE (s of the daemon's clock).
    settle_timeout_s: float = 3600.0


@dataclass(frozen=True)
class SimulationConfig:
    model: Path | None
    seed: int
    transport: str


@dataclass(frozen=True)
class DaemonConfig:
    """The whole daemon configuration (see ``config/cryod.yaml`` for every key)."""

    loop: LoopConfig
    instruments: InstrumentsConfig
    sensors: SensorsConfig
    heater: HeaterConfig
    control: ControlConfig
    safety: SafetyConfig
    data: DataConfig
    control_socket: SocketConfig
    simulation: SimulationConfig
    metrics: MetricsConfig = MetricsConfig()
    web: WebConfig | None = None
    lakeshore336: Lakeshore336Config | None = None
    alarms: AlarmsConfig = AlarmsConfig()
    ioc: IocConfig | None = None
    source: str = ""
    text: str = ""

    def restart_needed_for(self, new: "DaemonConfig") -> list[str]:
        """Keys that differ in ``new`` but cannot be changed on a running daemon.

        The sections ``control``, ``safety`` and ``alarms`` and ``loop.overrun_streak_limit`` change
        on reload (SIGHUP); everything else needs a restart.
        """
        changed = []
        for field in dataclasses.fields(self):
            name = field.name
            if name in ("source", "text", "control", "safety", "alarms"):
                continue
            old_value, new_value = getattr(self, name), getattr(new, name)
            if name == "loop":
                old_value = dataclasses.replace(old_value, overrun_streak_limit=0)
                new_value = dataclasses.replace(new_value, overrun_streak_limit=0)
            if old_value != new_value:
                changed.append(name)
        return changed


def load_config(path: str | Path) -> DaemonConfig:
    """Read and validate a daemon configuration file.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    DaemonConfig

    Raises
    ------
    cryod.yaml_source.FileFormatError
        For a missing file, invalid YAML, an unknown or missing key, a wrong
        type, a value out of range or a file it names that does not exist;
        the message names the file, the line and the key.
    """
    path = Path(path)
    text = read_text_file(path)            # read once: the recorded text is the text that was parsed
    config = _config_from_section(Section.from_text(text, str(path)), path.resolve().parent)
    return dataclasses.replace(config, source=str(path), text=text)


def located_error(config: DaemonConfig, dotted_key: str, reason: str) -> FileFormatError:
    """An error at ``dotted_key`` (``"safety.ptc_stage_max_K"``) of the file ``config`` was read from.

    For checks made after loading (against a model, an instrument): the message names the file,
    the line of the key in the text that was loaded, and the key, like every configuration error.
    """
    line = None
    if config.text:
        section = Section.from_text(config.text, config.source)
        *parents, key = dotted_key.split(".")
        for parent in parents:
            section = section.section(parent)
        line = section.line_of(key)
    return FileFormatError(config.source, line, dotted_key, reason)


_REQUIRED = object()


def _path_value(section: Section, key: str, base: Path, default=_REQUIRED) -> Path | None:
    """A path setting, relative to the configuration's folder; empty text is refused.

    Without ``default`` the key is required; with ``default=None`` a missing key or null gives None.
    """
    value = section.text(key) if default is _REQUIRED else section.text(key, default)
    if value is None:
        return None
    if not value.strip():
        raise section.error(key, "is empty: give a path")
    if "\0" in value:
        raise section.error(key, f"contains a NUL character: {shown(value)}")
    try:
        candidate = Path(value).expanduser()
    except RuntimeError as error:          # ~user of a user that does not exist
        raise section.error(key, f"{error}: {shown(value)}") from None
    return candidate if candidate.is_absolute() else base / candidate


def _existing_file(section: Section, key: str, base: Path, default=_REQUIRED) -> Path | None:
    candidate = _path_value(section, key, base, default)
    if candidate is None:
        return None
    if candidate.is_dir():
        raise section.error(key, f"is a directory, not a file: {candidate}")
    if not candidate.exists():
        raise section.error(key, f"file not found: {candidate}")
    if not candidate.is_file():
        raise section.error(key, f"not a regular file: {candidate}")
    return candidate


def _directory(section: Section, key: str, base: Path) -> Path:
    """A directory that may not exist yet; a file in its place (or in a parent's) is refused."""
    candidate = _path_value(section, key, base)
    for place in (candidate, *candidate.parents):
        if place.exists():
            if not place.is_dir():
                what = "is a file" if place == candidate else f"is inside {place}, which is a file"
                raise section.error(key, f"{candidate} {what}, not a directory")
            break
    return candidate


def _socket_path(section: Section, key: str, base: Path) -> Path:
    candidate = _path_value(section, key, base)
    if candidate.is_dir():
        raise section.error(key, f"{candidate} is a directory: give the socket's own path in it, "
                                 f"e.g. {candidate / 'control.sock'}")
    length = len(os.fsencode(str(candidate)))
    if length > SOCKET_PATH_MAX_BYTES:
        raise section.error(key, f"{length} bytes long: a Unix socket's path holds at most {SOCKET_PATH_MAX_BYTES} "
                                 f"bytes; give a shorter one (e.g. /run/cryod/control.sock)")
    return candidate


def _calibration(section: Section, key: str, base: Path) -> tuple[Path, CalibrationCurve]:
    path = _existing_file(section, key, base)
    try:
        return path, load_calibration(path)
    except FileFormatError as error:
        raise section.error(key, f"calibration not usable: {error}") from None


def _covers(curve: CalibrationCurve, low_K: float, high_K: float) -> bool:
    """Whether the curve's calibrated temperatures cover ``low_K..high_K`` without a gap."""
    spans: list[list[float]] = []
    for start, end in curve.calibrated_temperature_ranges_K:
        if spans and start <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], end)
        else:
            spans.append([start, end])
    return any(start <= low_K and high_K <= end for start, end in spans)


def _range_text(curve: CalibrationCurve) -> str:
    ranges = curve.calibrated_temperature_ranges_K
    return " and ".join(f"{low:.5g}..{high:.5g} K" for low, high in ranges)


def _address(section: Section) -> tuple[InstrumentAddress, str, Section, str]:
    """The instrument's address, its canonical form (:mod:`drivers.transports.addresses`: what the host-wide
    instrument lock takes), and the section and key that say so (for later errors)."""
    from drivers.transports.addresses import instrument_resource, prologix_instrument

    resource = section.text("resource", None)
    prologix = section.section("prologix", None)
    if (resource is None) == (prologix is None):
        raise section.error(None, "give either 'resource' (a VISA resource) or 'prologix' (adapter and address)")
    if prologix is not None:
        port = prologix.text("port", None)
        host = prologix.text("host", None)
        if (port is None) == (host is None):
            raise prologix.error(None, "give either 'port' (GPIB-USB serial device) or 'host' (GPIB-ETHERNET)")
        if not (port or host or "").strip():
            raise prologix.error("port" if port is not None else "host", "is empty")
        address = InstrumentAddress(prologix_port=port, prologix_host=host,
                                    gpib_address=prologix.number("address", minimum=0, maximum=30, integer=True))
        prologix.finish()
        try:
            canonical = prologix_instrument(port=port, host=host, gpib_address=address.gpib_address)
        except ValueError as error:
            raise prologix.error("port" if port is not None else "host", str(error)) from None
        return address, canonical, prologix, "address"
    try:
        canonical = instrument_resource(resource)
    except ValueError as error:
        raise section.error("resource", f"not a VISA resource cryod can open: {error}") from None
    return InstrumentAddress(resource=resource), canonical, section, "resource"


def _instruments_apart(places: dict) -> None:
    """Refuse two instruments at one address (the second one named, with the first): one address, one lock."""
    seen: dict = {}
    for name, (_, canonical, section, key) in places.items():
        if canonical in seen:
            raise section.error(key, f"{canonical} is instruments.{seen[canonical]}'s already: two instruments "
                                     f"cannot share an address")
        seen[canonical] = name


def _trigger_reaches_both_dmms(trigger: str, places: dict, section: Section) -> None:
    """``gpib-group`` needs both DMMs on one GPIB card, ``prologix`` both behind one Prologix controller."""
    from pyvisa import rname

    from drivers.transports.addresses import canonical_prologix_adapter

    dmms = [places[name][0] for name in ("flange_dmm", "ptc_stage_dmm")]
    described = " and ".join(f"the {name} DMM is {address.resource or 'behind a Prologix controller'}"
                             for name, address in zip(("flange", "PTC-stage"), dmms))
    if trigger == "gpib-group":
        parsed = [rname.parse_resource_name(places[name][1]) for name in ("flange_dmm", "ptc_stage_dmm")
                  if places[name][0].resource]
        if len(parsed) != 2 or not all(isinstance(each, rname.GPIBInstr) for each in parsed) \
                or parsed[0].board != parsed[1].board:
            raise section.error("trigger", f"gpib-group triggers both DMMs on one GPIB card, but {described}: give "
                                           f"both GPIBn::address::INSTR resources on one board, or another trigger")
    if trigger == "prologix":
        adapters = {canonical_prologix_adapter(port=address.prologix_port, host=address.prologix_host)
                    for address in dmms if not address.resource}
        if any(address.resource for address in dmms) or len(adapters) != 1:
            raise section.error("trigger", f"prologix triggers both DMMs behind one Prologix controller, but "
                                           f"{described}: give both a prologix: section with the same port or host")


def _config_from_section(top: Section, base: Path) -> DaemonConfig:
    config_format = top.text("format")
    if config_format != CONFIG_FORMAT:
        raise top.error("format", f"expected '{CONFIG_FORMAT}', got {config_format!r}")

    loop_section = section = top.section("loop")
    loop = LoopConfig(
        period_s=section.number("period_s", 0.08, minimum=0.01, maximum=10.0),
        overrun_streak_limit=section.number("overrun_streak_limit", 5, minimum=1, maximum=1000, integer=True),
        realtime_priority=section.number("realtime_priority", 20, minimum=0, maximum=99, integer=True),
        lock_memory=section.flag("lock_memory", True),
    )
    section.finish()

    section = top.section("instruments")
    dmm_section = section.section("dmm")
    dmm = DmmSettings(
        range_ohm=dmm_section.number("range_ohm", minimum=0.0, exclusive_minimum=True),
        nplc=dmm_section.number("nplc", minimum=0.01, maximum=50.0),
        digits=dmm_section.number("digits", 7, minimum=4, maximum=9, integer=True),
        filter_count=dmm_section.number("filter_count", 1, minimum=1, maximum=100, integer=True),
        autozero=dmm_section.flag("autozero", True),
        autozero_synchronous=dmm_section.text("autozero_type", "synchronous",
                                              choices=("synchronous", "normal")) == "synchronous",
        offset_compensation=dmm_section.flag("offset_compensation", False),
        line_sync=dmm_section.flag("line_sync", True),
        line_frequency_hz=dmm_section.number("line_frequency_hz", 50.0, minimum=50.0, maximum=60.0),
    )
    if dmm.line_frequency_hz not in (50.0, 60.0):
        raise dmm_section.error("line_frequency_hz", f"must be 50 or 60, got {dmm.line_frequency_hz:g}")
    dmm_section.finish()
    heater_section = section.section("heater_supply")
    heater_model = heater_section.text("model", choices=HEATER_MODELS)
    places = {"heater_supply": _address(heater_section)}
    heater_section.finish()
    for name in ("flange_dmm", "ptc_stage_dmm"):
        instrument_section = section.section(name)
        places[name] = _address(instrument_section)
        instrument_section.finish()
    _instruments_apart(places)
    trigger = section.text("trigger", choices=TRIGGER_MODES)
    _trigger_reaches_both_dmms(trigger, places, section)
    output_section = section.section("trigger_output", None)
    trigger_output = None
    if output_section is not None:
        trigger_output = TriggerOutputConfig(
            port=output_section.text("port"),
            line=output_section.text("line", "rts", choices=("rts", "dtr")),
            dmm_input=output_section.text("dmm_input", "external", choices=("external", "trigger_link")),
            link_line=output_section.number("link_line", 1, minimum=1, maximum=6, integer=True),
        )
        output_section.finish()
    elif trigger == "external":
        raise section.error("trigger", "external needs instruments.trigger_output: {port: /dev/ttyS0, line: rts}")
    instruments = InstrumentsConfig(
        trigger=trigger,
        trigger_output=trigger_output,
        timeout_s=section.number("timeout_s", 1.0, minimum=0.01, maximum=60.0),
        visa_library=section.text("visa_library", "@py"),
        flange_dmm=places["flange_dmm"][0],
        ptc_stage_dmm=places["ptc_stage_dmm"][0],
        heater_supply=places["heater_supply"][0],
        heater_model=heater_model,
        dmm=dmm,
        lock_directory=(_directory(section, "lock_directory", base) if section.text("lock_directory", None) is not None
                        else DEFAULT_LOCK_DIRECTORY),
    )
    timing = ReadingTiming(nplc=dmm.nplc, line_frequency_hz=dmm.line_frequency_hz,
                           offset_compensation=dmm.offset_compensation, autozero=dmm.autozero,
                           autozero_synchronous=dmm.autozero_synchronous, line_sync=dmm.line_sync,
                           conversions_per_reading=dmm.filter_count)
    if timing.worst_case_delay_s + CYCLE_MARGIN_S > loop.period_s:
        raise dmm_section.error("nplc", f"{dmm.nplc:g} PLC: a reading can take {timing.worst_case_delay_s * 1e3:.0f} ms "
                                        f"(autozero, offset compensation, filter and line sync included), which "
                                        f"leaves no time in a {loop.period_s * 1e3:.0f} ms loop period (at least "
                                        f"{CYCLE_MARGIN_S * 1e3:.0f} ms are needed to fetch, convert and set the "
                                        f"heater)")
    _check_waits_against_watchdog(InstrumentWaits(loop.period_s, instruments.timeout_s), section, loop_section)
    section.finish()

    section = top.section("sensors")
    flange = section.section("flange")
    stage = section.section("ptc_stage")
    flange_path, flange_curve = _calibration(flange, "calibration", base)
    stage_path, stage_curve = _calibration(stage, "calibration", base)
    sensors = SensorsConfig(flange_calibration=flange_path, ptc_stage_calibration=stage_path)
    flange.finish()
    stage.finish()
    section.finish()

    section = top.section("heater")
    heater = HeaterConfig(
        resistance_ohm=section.number("resistance_ohm", minimum=0.0, exclusive_minimum=True, maximum=1e5),
        max_current_A=section.number("max_current_A", 0.1, minimum=0.0, exclusive_minimum=True, maximum=0.105),
        voltage_compliance_V=section.number("voltage_compliance_V", minimum=0.1, maximum=105.0),
    )
    if heater.resistance_ohm * heater.max_current_A > heater.voltage_compliance_V:
        raise section.error("voltage_compliance_V",
                            f"{heater.voltage_compliance_V:g} V cannot drive {heater.max_current_A:g} A through "
                            f"{heater.resistance_ohm:g} ohm (needs {heater.resistance_ohm * heater.max_current_A:g} V)")
    section.finish()

    safety_section = section = top.section("safety")
    safety = SafetyConfig(
        flange_max_K=section.number("flange_max_K", minimum=0.0, exclusive_minimum=True, maximum=400.0),
        ptc_stage_max_K=section.number("ptc_stage_max_K", minimum=0.0, exclusive_minimum=True, maximum=400.0),
        max_repeated_readings=section.number("max_repeated_readings", 50, minimum=2, maximum=1000, integer=True),
        valid_readings_to_resume=section.number("valid_readings_to_resume", 5, minimum=1, maximum=1000, integer=True),
        recovery_timeout_s=section.number("recovery_timeout_s", 60.0, minimum=0.0, maximum=86400.0),
        instruments_wait_s=section.number("instruments_wait_s", None, minimum=0.0),
        max_reading_age_s=section.number("max_reading_age_s", 0.5, minimum=2.0 * loop.period_s, maximum=60.0),
    )
    section.finish()

    control_section = top.section("control")
    control = _control(control_section, safety, heater)
    _check_limits_against_calibrations(control, control_section, safety, safety_section,
                                       (flange_curve, flange), (stage_curve, stage))

    section = top.section("data")
    data = DataConfig(
        directory=_directory(section, "directory", base),
        fsync_interval_s=section.number("fsync_interval_s", 2.0, minimum=0.01, maximum=2.0),
        warn_free_MB=section.number("warn_free_MB", 1000.0, minimum=0.0, maximum=1e9),
        min_free_MB=section.number("min_free_MB", 100.0, minimum=1.0, maximum=1e9),
        compress_finished=section.flag("compress_finished", True),
    )
    if data.warn_free_MB < data.min_free_MB:
        raise section.error("warn_free_MB", f"{data.warn_free_MB:g} MB is below data.min_free_MB "
                                            f"{data.min_free_MB:g} MB: the warning would come after the stop")
    section.finish()

    section = top.section("control_socket")
    socket_config = SocketConfig(
        path=_socket_path(section, "path", base),
        mode=section.file_mode("mode", 0o660),
        owner=section.text("owner", None),
        group=section.text("group", None),
    )
    if socket_config.mode & SOCKET_MODE_OTHERS:
        raise section.error("mode", f"{socket_config.mode:04o} lets every user of this computer reach the "
                                    f"socket, and whoever reaches it sets the heater: give owner and group "
                                    f"only, e.g. \"0660\" (and control_socket.group for the lab's users)")
    section.finish()

    section = top.section("simulation", None)
    simulation = SimulationConfig(model=None, seed=0, transport="tcp")
    if section is not None:
        simulation = SimulationConfig(
            model=_existing_file(section, "model", base, None),
            seed=section.number("seed", 0, minimum=0, integer=True),
            transport=section.text("transport", "tcp", choices=SIMULATION_TRANSPORTS),
        )
        section.finish()
    metrics = _metrics(top.section("metrics", None))
    web = _web(top.section("web", None), base)
    lakeshore336 = _lakeshore336(top.section("lakeshore336", None))
    ioc = _ioc(top.section("ioc", None), base)
    alarms = alarms_from_section(top.section("alarms", None), safety.ptc_stage_max_K)
    top.finish()
    return DaemonConfig(loop=loop, instruments=instruments, sensors=sensors, heater=heater, control=control,
                        safety=safety, data=data, control_socket=socket_config, simulation=simulation,
                        metrics=metrics, web=web, lakeshore336=lakeshore336, alarms=alarms, ioc=ioc)


def _check_waits_against_watchdog(waits: InstrumentWaits, instruments_section: Section,
                                  loop_section: Section) -> None:
    """``instruments.timeout_s`` (or a ``loop.period_s`` no timeout fits) that could leave systemd's
    watchdog unfed: each tick feeds it, and the longest tick follows from these two
    (:mod:`cryod.instrument_waits`)."""
    problem = waits.watchdog_problem()
    if problem is None:
        return
    if waits.largest_timeout_s() < 0.01:
        raise loop_section.error("period_s", f"{waits.loop_period_s:g} s: {problem}")
    raise instruments_section.error("timeout_s", problem)


def _metrics(section: Section | None) -> MetricsConfig:
    if section is None:
        return MetricsConfig()
    address = section.text("address", None)
    if address is not None:
        try:
            parse_address(address, host_names=True)
        except ValueError as error:
            raise section.error("address", str(error)) from None
    metrics = MetricsConfig(address=address, cryostat=section.text("cryostat", ""))
    section.finish()
    return metrics


def _listen_address(section: Section) -> str:
    """The section's ``address`` (host:port), checked; port 0 (any free port) is taken for tests."""
    address = section.text("address")
    try:
        parse_address(address, allow_any_port=True)
    except ValueError as error:
        raise section.error("address", str(error)) from None
    return address


def _web(section: Section | None, base: Path) -> WebConfig | None:
    if section is None:
        return None
    web = WebConfig(address=_listen_address(section), writable=section.flag("writable", False),
                    token_file=_existing_file(section, "token_file", base, None),
                    allowed_hosts=tuple(_host_name(section, "allowed_hosts", name)
                                        for name in section.texts("allowed_hosts", [])))
    if web.writable and web.token_file is None:
        raise section.error("writable", "control from the page needs web.token_file: a file holding the token "
                                        "a write must carry (at least 16 characters), readable by the service's "
                                        "group only (docs/reference/configuration.md)")
    if web.token_file is not None:
        try:
            read_token(web.token_file)
        except ValueError as error:
            raise section.error("token_file", str(error)) from None
    section.finish()
    return web


def _lakeshore336(section: Section | None) -> Lakeshore336Config | None:
    if section is None:
        return None
    lakeshore = Lakeshore336Config(address=_listen_address(section), writable=section.flag("writable", False),
                                   write_from=tuple(_ip_address(section, "write_from", text)
                                                    for text in section.texts("write_from", [])))
    section.finish()
    return lakeshore


def _ioc(section: Section | None, base: Path) -> IocConfig | None:
    if section is None:
        return None
    prefix = section.text("prefix")
    bad = sorted(set(prefix) - PV_NAME_CHARACTERS)
    if not prefix or bad:
        raise section.error("prefix", f"{shown(prefix)} is not the start of an EPICS record name: give letters, digits "
                                      f"and _ - + : [ ] < > ; only (e.g. CRYO1:)" +
                                      (f", not {' '.join(repr(character) for character in bad)}" if bad else ""))
    if len(prefix) > MAX_PV_PREFIX:
        raise section.error("prefix", f"{len(prefix)} characters: EPICS record names hold at most 60, and the "
                                      f"names after the prefix take up to 20; give at most {MAX_PV_PREFIX}")
    ioc = IocConfig(prefix=prefix, writable=section.flag("writable", False),
                    access_security_file=_existing_file(section, "access_security_file", base, None),
                    stable_tolerance_K=section.number("stable_tolerance_K", 1e-4, minimum=0.0,
                                                      exclusive_minimum=True),
                    stable_hold_s=section.number("stable_hold_s", 60.0, minimum=0.0),
                    settle_timeout_s=section.number("settle_timeout_s", 3600.0, minimum=0.0,
                                                    exclusive_minimum=True))
    section.finish()
    return ioc


def _host_name(section: Section, key: str, text: str) -> str:
    """A host name or address as a ``Host`` header gives it (lower case, no port)."""
    name = text.strip().lower()
    if not name or not all(character.isalnum() or character in ".-:_[]" for character in name):
        raise section.error(key, f"{text!r} is not a host name or address (give names without a port)")
    return name.strip("[]")


def _ip_address(section: Section, key: str, text: str) -> str:
    """An IP address, as the kernel gives a peer's."""
    import ipaddress

    try:
        return str(ipaddress.ip_address(text.strip()))
    except ValueError:
        raise section.error(key, f"{text!r} is not an IP address (give each computer's address)") from None


def _control(section: Section, safety: SafetyConfig, heater: HeaterConfig) -> ControlConfig:
    setpoint_min = section.number("setpoint_min_K", 1.0, minimum=0.0, exclusive_minimum=True)
    setpoint_max = section.number("setpoint_max_K", minimum=0.0, exclusive_minimum=True)
    if setpoint_max <= setpoint_min:
        raise section.error("setpoint_max_K", f"must be above setpoint_min_K ({setpoint_min:g} K)")
    if setpoint_max >= safety.flange_max_K:
        raise section.error("setpoint_max_K", f"must be below the over-temperature limit safety.flange_max_K "
                                              f"({safety.flange_max_K:g} K)")
    max_ramp = section.number("max_ramp_K_per_min", 10.0, minimum=0.0, exclusive_minimum=True)
    if max_ramp < MIN_RATE_K_PER_MIN:
        raise section.error("max_ramp_K_per_min", f"{max_ramp!r} K/min would allow no ramp that moves the "
                                                  f"setpoint: at least {MIN_RATE_K_PER_MIN:g} K/min")
    if max_ramp > MAX_RAMP_K_PER_MIN:
        raise section.error("max_ramp_K_per_min", f"{max_ramp:g} K/min is beyond what a cryostat flange can "
                                                  f"follow; at most {MAX_RAMP_K_PER_MIN:g} K/min (a Lake Shore "
                                                  f"controller's fastest ramp; a flange on a 4 K cooler "
                                                  f"follows a few K/min)")
    setpoint = section.number("setpoint_K", None)
    if setpoint is not None and not setpoint_min <= setpoint <= setpoint_max:
        raise section.error("setpoint_K", f"{setpoint:g} K is outside {setpoint_min:g}..{setpoint_max:g} K "
                                          f"(control.setpoint_min_K, control.setpoint_max_K)")
    for moved in MOVED_TO_PI:
        if moved in section.data:
            raise section.error(moved, f"the PI gains have a section of their own: give it as control.pi.{moved}")
    ramp = section.number("ramp_K_per_min", 0.0, minimum=0.0, maximum=max_ramp)
    if rate_refusal(ramp) is not None:
        raise section.error("ramp_K_per_min", rate_refusal(ramp))
    control = ControlConfig(
        setpoint_K=setpoint,
        ramp_K_per_min=ramp,
        setpoint_min_K=setpoint_min,
        setpoint_max_K=setpoint_max,
        max_ramp_K_per_min=max_ramp,
        terms=term_settings_from(section),
        zones=zone_table_from(section, setpoint_min, setpoint_max, heater.max_power_w),
    )
    section.finish()
    return control


def _check_limits_against_calibrations(control: ControlConfig, control_section: Section, safety: SafetyConfig,
                                       safety_section: Section, flange, stage) -> None:
    """The setpoint range and the over-temperature limits against each other and the sensors' curves.

    The flange curve must cover ``setpoint_min_K`` up to ``flange_max_K`` without a gap (T2 must be
    readable wherever the loop may regulate, and up to its limit, or an over-temperature would show
    as a reading out of calibration instead). The PTC-stage limit must lie inside its curve, above
    its lowest temperature: a limit at or below it would hold the heater off at every reading.
    """
    flange_curve, flange_section = flange
    stage_curve, stage_section = stage
    flange_file = f"{flange_curve.source} (sensors.flange.calibration) covers {_range_text(flange_curve)}"
    stage_file = f"{stage_curve.source} (sensors.ptc_stage.calibration) covers {_range_text(stage_curve)}"
    if not _covers(flange_curve, control.setpoint_min_K, control.setpoint_min_K):
        raise control_section.error("setpoint_min_K", f"{control.setpoint_min_K:g} K is outside the flange "
                                                      f"thermometer's calibration: {flange_file}")
    if not _covers(flange_curve, safety.flange_max_K, safety.flange_max_K):
        raise safety_section.error("flange_max_K", f"{safety.flange_max_K:g} K is outside the flange "
                                                   f"thermometer's calibration, so T2 could never be read "
                                                   f"at this limit: {flange_file}")
    if not _covers(flange_curve, control.setpoint_min_K, safety.flange_max_K):
        raise control_section.error("setpoint_max_K", f"the flange thermometer's calibration has a gap "
                                                      f"between control.setpoint_min_K "
                                                      f"{control.setpoint_min_K:g} K and safety.flange_max_K "
                                                      f"{safety.flange_max_K:g} K: {flange_file}")
    lowest_K = stage_curve.temperature_range_K[0]
    if safety.ptc_stage_max_K <= lowest_K:
        raise safety_section.error("ptc_stage_max_K", f"{safety.ptc_stage_max_K:g} K is at or below the lowest "
                                                      f"temperature the PTC-stage thermometer can read "
                                                      f"({lowest_K:g} K): every reading would be above it and "
                                                      f"the heater held off for good; {stage_file}")
    if not _covers(stage_curve, safety.ptc_stage_max_K, safety.ptc_stage_max_K):
        raise safety_section.error("ptc_stage_max_K", f"{safety.ptc_stage_max_K:g} K is outside the PTC-stage "
                                                      f"thermometer's calibration, so T5 could never be read at "
                                                      f"this limit: {stage_file}")


__all__ = ["DaemonConfig", "FileFormatError", "load_config", "located_error", "EXAMPLE_CONFIG_PATH"]
