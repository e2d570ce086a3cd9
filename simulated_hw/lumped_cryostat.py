"""An independent simulated cryostat: a lumped thermal network integrated in time, for benchmarking the analysis.

``cryod analyze`` fits effects of :mod:`cryod.model` (docs/explanation/cryostat-model.md, "Optional effects"), and the project's own
records (:mod:`simulated_hw.measurement_programs`) are made by the same model family, so they share the analysis'
blind spots: an effect there has exactly the form the analysis fits. This module makes records another way, with
nothing of :mod:`cryod.model` (it imports numpy only): the cryostat is a network of heat capacities and thermal
conductances, integrated with a fourth-order Runge-Kutta step of 10 ms, the cooler's oscillation is a heat input
in continuous time, and each effect has a physical form the catalogue does not use:

=============================  ===========================================================================
effect (closest catalogue cause)  the form here
=============================  ===========================================================================
thermometer lag (``sensor_lag``)   the flange thermometer is a body on a mount, each with its own heat capacity
                                   and thermal link (two coupled nodes: a second-order lag, the mount loaded by
                                   the body), 70 % of the lag in the body and 30 % in the mount
link (``link_dynamics``)           the cooler's heat reaches the flange through two masses in a row instead of
                                   one (a coupled RC ladder), with its heat scaled by a gain
transport delay (``dead_time``)    the heater's power reaches the flange plate ``delay`` seconds late, evaluated
                                   at each Runge-Kutta stage (not at the rows' instants)
heat capacity (``heat_capacity_temperature``)  each flange node's heat capacity follows copper's
                                   ``gamma T + beta T^3`` at its own temperature, raised to a power ``p``
                                   (the catalogue scales time constants by ``(T2 / T_ref)^n``)
heater that sags (``heater_nonlinearity``)  delivered power ``P (1 + c P^2)`` (the catalogue's is ``P + k P^2``)
=============================  ===========================================================================

The network, as deviations from the zero-heater operating point (4.23 K, 3.34 K):

* the flange plate (heater and thermometer on it), heat capacity ``C2``, tied to the cooler through the
  flexible link's conductance ``K2`` and to a hanging mass (the pressure vessel) through ``K12``;
* the hanging mass, ``C1``;
* the link's end at the flange, ``CL``, fed by the cooler's oscillating heat ``q = H dT5_osc/dt`` and
  conducting it to the plate through ``KL``;
* the cooler's second stage, warmed by the heater's power through its own load line (``CS``, ``KS``), with the
  oscillation ``B sin(phi(t))`` on top.

Its heat capacities and conductances are chosen so that, without effects, the record shows what the shipped
model's transfer functions say (the heater's path to T2 and T5, the line's gain and phase on T2): the analysis
is given the shipped model, and a clean record of this network must be a clean record to it. Each record's
network is then moved by a few percent (``spread``), as a real cryostat is off its model.

Examples
--------
>>> cryostat = LumpedCryostat.nominal()
>>> record = run_protocol(cryostat, "pi_only", duration_s=120.0, seed=1)
>>> sorted(record)[:3], bool(0.0 <= record["heater_W"].min() <= record["heater_W"].max() <= HEATER_MAX_W)
(['T2_K', 'T5_K', 'heater_W'], True)
"""

from __future__ import annotations

import bisect
import cmath
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

#: What the shipped model says (config/model.yaml), written out here so that nothing is taken from cryod.model:
#: heater to T2 (338.42 s + 6.8182) / ((26.48 s + 1)(165.41 s + 1)) K/W, heater to T5 2.77 / (135 s + 1) K/W, and
#: T2's line over T5's at 10.83 rad/s: G2 G_link C j omega with G2 = 1 / (26.48 s + 1), G_link = 5.333 /
#: (0.1996 s + 1) K/W, C = 0.1655 J/K.
SHIPPED_FLANGE_GAIN_K_PER_W = 6.8182
SHIPPED_FLANGE_ZERO_S = 338.42 / 6.8182
SHIPPED_FLANGE_POLES_S = (26.48, 165.41)
SHIPPED_STAGE_GAIN_K_PER_W = 2.77
SHIPPED_STAGE_TIME_CONSTANT_S = 135.0
SHIPPED_LINK = (5.333, 0.1996, 0.1655)
FLANGE_ZERO_HEATER_K = 4.23
STAGE_ZERO_HEATER_K = 3.34
LINE_RAD_S = 10.83
LINE_AMPLITUDE_K = 0.12361
#: Copper's heat capacity per mole, gamma T + beta T^3 (J/(mol K^2), J/(mol K^4)).
COPPER_GAMMA = 0.695e-3
COPPER_BETA = 0.048e-3
#: Integration step (s) and the loop's period (s).
STEP_S = 0.01
PERIOD_S = 0.08
#: The records' heater (W) and PI gains (W/K, W/(K s)), as the lab's.
HEATER_MAX_W = 0.25
PI_GAINS = (0.4, 0.01)
#: Reading noise (K rms) of T2 and T5.
NOISE_K = (20e-6, 0.3e-3)
#: Share of a thermometer's lag in its body (the rest in its mount), and the body's heat capacity over the mount's.
THERMOMETER_BODY_SHARE = 0.7
THERMOMETER_BODY_OVER_MOUNT = 0.5


@dataclass(frozen=True, kw_only=True)
class Effects:
    """The effects of one record (zero: absent).

    Attributes
    ----------
    thermometer_lag_s : float
        The flange thermometer's lag, body and mount together (s).
    link_time_constant_s, link_gain : float
        The second mass of the link (its time constant, s) and the scale of the cooler's heat.
    delay_s : float
        Transport delay of the heater's power to the flange plate (s).
    heat_capacity_power : float
        ``p`` of each flange node's heat capacity ``(c(T) / c(T_ref))^p``, c copper's.
    heater_sag_per_W2 : float
        ``c`` of the delivered power ``P (1 + c P^2)``.
    """

    thermometer_lag_s: float = 0.0
    link_time_constant_s: float = 0.0
    link_gain: float = 1.0
    delay_s: float = 0.0
    heat_capacity_power: float = 0.0
    heater_sag_per_W2: float = 0.0


@dataclass(frozen=True, kw_only=True)
class LumpedCryostat:
    """The network's heat capacities (J/K) and conductances (W/K), the cooler's line and the effects."""

    plate_capacity: float
    mass_capacity: float
    plate_to_cooler: float
    plate_to_mass: float
    link_capacity: float
    link_conductance: float
    heat_per_kelvin: float
    stage_capacity: float
    stage_conductance: float
    line_rad_s: float = LINE_RAD_S
    line_amplitude_K: float = LINE_AMPLITUDE_K
    line_phase_rad: float = 0.0
    effects: Effects = Effects()

    @classmethod
    def nominal(cls) -> "LumpedCryostat":
        """The network whose clean record is the shipped model's (see the module doc)."""
        k2 = 1.0 / SHIPPED_FLANGE_GAIN_K_PER_W
        poles = SHIPPED_FLANGE_POLES_S
        product, total = poles[0] * poles[1], poles[0] + poles[1]
        c2 = product / SHIPPED_FLANGE_ZERO_S * k2
        k12 = k2 * ((total - c2 / k2) / SHIPPED_FLANGE_ZERO_S - 1.0)
        c1 = SHIPPED_FLANGE_ZERO_S * k12
        stage_conductance = 1.0 / SHIPPED_STAGE_GAIN_K_PER_W
        plain = cls(plate_capacity=c2, mass_capacity=c1, plate_to_cooler=k2, plate_to_mass=k12, link_capacity=1.0,
                    link_conductance=1.0, heat_per_kelvin=1.0, stage_capacity=SHIPPED_STAGE_TIME_CONSTANT_S
                    * stage_conductance, stage_conductance=stage_conductance)
        return plain.with_line_matched()

    def plate_response(self, omega: float) -> complex:
        """The plate's temperature per watt put into it at ``omega`` (rad/s)."""
        s = 1j * omega
        mass = self.mass_capacity * s + self.plate_to_mass
        return mass / ((self.plate_capacity * s + self.plate_to_cooler + self.plate_to_mass) * mass
                       - self.plate_to_mass ** 2)

    def with_line_matched(self) -> "LumpedCryostat":
        """The link's time constant and the cooler's heat per kelvin set so that T2's line over T5's is the shipped
        model's at 10.83 rad/s (the link's end loads the plate little: its capacity is a hundredth of the plate's)."""
        gain, tau, capacity = SHIPPED_LINK
        omega = LINE_RAD_S
        wanted = gain / (1.0 + 1j * omega * tau) / (1.0 + 1j * omega * SHIPPED_FLANGE_POLES_S[0]) * capacity
        plate = self.plate_response(omega)
        link = wanted / plate                       # heat reaching the plate per unit of C dT5/dt
        link_tau = math.tan(-cmath.phase(link)) / omega
        link_capacity = self.plate_capacity / 100.0
        return dataclasses.replace(self, link_capacity=link_capacity, link_conductance=link_capacity / link_tau,
                                   heat_per_kelvin=abs(link) * math.hypot(1.0, omega * link_tau))

    def spread(self, generator: np.random.Generator, fraction: float = 0.03) -> "LumpedCryostat":
        """Every heat capacity and conductance moved by a factor within ``1 +- fraction``, and the cooler's line
        another day's: its phase, and up to 1 % in frequency and 10 % in amplitude."""
        fields = ("plate_capacity", "mass_capacity", "plate_to_cooler", "plate_to_mass", "link_capacity",
                  "link_conductance", "heat_per_kelvin", "stage_capacity", "stage_conductance")
        moved = {name: getattr(self, name) * float(1.0 + generator.uniform(-fraction, fraction)) for name in fields}
        return dataclasses.replace(self, **moved, line_rad_s=LINE_RAD_S * float(generator.uniform(0.99, 1.0)),
                                   line_amplitude_K=LINE_AMPLITUDE_K * float(generator.uniform(0.9, 1.0)),
                                   line_phase_rad=float(generator.uniform(-math.pi, math.pi)))

    def with_effects(self, effects: Effects) -> "LumpedCryostat":
        return dataclasses.replace(self, effects=effects)


def copper_heat_capacity(temperature_K: float) -> float:
    """Copper's molar heat capacity, gamma T + beta T^3 (J/(mol K))."""
    return COPPER_GAMMA * temperature_K + COPPER_BETA * temperature_K ** 3


class _Network:
    """The network's equations, integrated with a Runge-Kutta step (see the module doc).

    The state: plate, hanging mass, link's end, link's second mass, thermometer's mount, thermometer's body, stage
    (deviations from the operating point, K). A node an effect does not use follows its neighbour at once.
    """

    def __init__(self, cryostat: LumpedCryostat):
        self.cryostat = cryostat
        effects = cryostat.effects
        self.reference = copper_heat_capacity(FLANGE_ZERO_HEATER_K)
        lag = effects.thermometer_lag_s
        self.body_tau = THERMOMETER_BODY_SHARE * lag
        self.mount_tau = (1.0 - THERMOMETER_BODY_SHARE) * lag
        self.second_link_tau = effects.link_time_constant_s
        self.history_t: list[float] = [-math.inf]
        self.history_p: list[float] = [0.0]

    def delivered(self, power_w: float) -> float:
        return power_w * (1.0 + self.cryostat.effects.heater_sag_per_W2 * power_w * power_w)

    def capacity_scale(self, deviation_K: float) -> float:
        power = self.cryostat.effects.heat_capacity_power
        if power == 0.0:
            return 1.0
        return (copper_heat_capacity(FLANGE_ZERO_HEATER_K + deviation_K) / self.reference) ** power

    def power_at(self, time_s: float) -> float:
        """The commanded power at ``time_s`` (held from each write until the next)."""
        return self.history_p[bisect.bisect_right(self.history_t, time_s) - 1]

    def derivative(self, time_s: float, state: list[float], power_w: float, cooler_heat_w: float) -> list[float]:
        c = self.cryostat
        plate, mass, link_end, link_second, mount, body, stage = state
        delay = c.effects.delay_s
        on_plate = self.delivered(self.power_at(time_s - delay) if delay > 0.0 else power_w)
        scale_plate, scale_mass = self.capacity_scale(plate), self.capacity_scale(mass)
        scale_link = self.capacity_scale(link_end)
        if self.second_link_tau > 0.0:
            # the cooler's heat into a first mass of the link, then the link's end: a ladder (the second loads the first)
            g = c.link_conductance * 2.0
            d_second = (c.effects.link_gain * cooler_heat_w - g * (link_second - link_end)) / (
                g * self.second_link_tau * scale_link)
            into_end = g * (link_second - link_end)
        else:
            d_second, into_end = 0.0, cooler_heat_w
        to_plate = c.link_conductance * (link_end - plate)
        d_end = (into_end - to_plate) / (c.link_capacity * scale_link)
        d_plate = (on_plate + to_plate - c.plate_to_cooler * plate - c.plate_to_mass * (plate - mass)) / (
            c.plate_capacity * scale_plate)
        d_mass = c.plate_to_mass * (plate - mass) / (c.mass_capacity * scale_mass)
        if self.body_tau > 0.0:
            mount_conductance = 1.0 / self.mount_tau        # per unit of the mount's heat capacity
            body_capacity = THERMOMETER_BODY_OVER_MOUNT
            body_conductance = body_capacity / self.body_tau
            to_body = body_conductance * (mount - body)
            d_mount = mount_conductance * (plate - mount) - to_body
            d_body = to_body / body_capacity
        else:
            d_mount = d_body = 0.0
        d_stage = (self.delivered(power_w) - c.stage_conductance * stage) / c.stage_capacity
        return [d_plate, d_mass, d_end, d_second, d_mount, d_body, d_stage]

    def cooler(self, time_s: float) -> tuple[float, float]:
        """The stage's oscillation (K) and the cooler's heat into the link (W) at ``time_s``."""
        c = self.cryostat
        phase = c.line_rad_s * time_s + c.line_phase_rad
        return (c.line_amplitude_K * math.sin(phase),
                c.heat_per_kelvin * c.line_amplitude_K * c.line_rad_s * math.cos(phase))

    def advance(self, time_s: float, state: list[float], power_w: float, duration_s: float) -> list[float]:
        """The state ``duration_s`` later, the heater held at ``power_w`` (Runge-Kutta, steps of :data:`STEP_S`)."""
        steps = max(1, int(round(duration_s / STEP_S)))
        h = duration_s / steps
        for _ in range(steps):
            q0 = self.cooler(time_s)[1]
            q1 = self.cooler(time_s + 0.5 * h)[1]
            q2 = self.cooler(time_s + h)[1]
            k1 = self.derivative(time_s, state, power_w, q0)
            k2 = self.derivative(time_s + 0.5 * h, [x + 0.5 * h * d for x, d in zip(state, k1)], power_w, q1)
            k3 = self.derivative(time_s + 0.5 * h, [x + 0.5 * h * d for x, d in zip(state, k2)], power_w, q1)
            k4 = self.derivative(time_s + h, [x + h * d for x, d in zip(state, k3)], power_w, q2)
            state = [x + h / 6.0 * (a + 2.0 * b + 2.0 * cc + d) for x, a, b, cc, d in zip(state, k1, k2, k3, k4)]
            time_s += h
        if self.body_tau <= 0.0:
            state[4] = state[5] = state[0]
        if self.second_link_tau <= 0.0:
            state[3] = state[2]
        return state

    def readings(self, time_s: float, state: list[float]) -> tuple[float, float]:
        """(T2, T5) without noise at ``time_s``."""
        flange = state[5] if self.body_tau > 0.0 else state[0]
        return FLANGE_ZERO_HEATER_K + flange, STAGE_ZERO_HEATER_K + state[6] + self.cooler(time_s)[0]

    def write(self, time_s: float, power_w: float) -> None:
        self.history_t.append(time_s)
        self.history_p.append(power_w)


def _settled_state(network: _Network) -> list[float]:
    """The zero-heater state at t = 0 with the cooler running for ever: each node at its steady oscillation.

    The equations are linear about the operating point (a heat capacity's law changes them by a part in a thousand
    over the line's millikelvins): with x' = A x + b q, q = Q cos(omega t + phi), the oscillation is Re(X Q e^(j
    (omega t + phi))) with X = (j omega - A)^-1 b; A and b are read from the equations themselves.
    """
    size = 7
    zero = [0.0] * size
    columns = []
    for index in range(size):
        unit = list(zero)
        unit[index] = 1e-6
        columns.append([value / 1e-6 for value in network.derivative(0.0, unit, 0.0, 0.0)])
    matrix = np.array(columns).T
    drive = np.array(network.derivative(0.0, zero, 0.0, 1.0))
    c = network.cryostat
    omega = c.line_rad_s
    response = np.linalg.solve(1j * omega * np.eye(size) - matrix, drive)
    heat = c.heat_per_kelvin * c.line_amplitude_K * omega * cmath.exp(1j * c.line_phase_rad)
    state = [float((value * heat).real) for value in response]
    if network.body_tau <= 0.0:
        state[4] = state[5] = state[0]
    if network.second_link_tau <= 0.0:
        state[3] = state[2]
    return state


def protocol_schedule(protocol: str, duration_s: float) -> list[tuple[float, str, object]]:
    """(start s, ``"power"`` or ``"setpoint"``, W or K or a function of time) segments of a protocol.

    * ``identification``: holds and steps (0, 10, 30 mW), 20 +- 15 mW at the line and at 2.5 rad/s, PI to 5 K,
      holds at 110 and 140 mW, PI to 4.6 K, scaled to ``duration_s`` (an hour);
    * ``pi_only``: PI from the zero-heater point to 5 K (the paper's Fig. 6);
    * ``paper``: the paper's two experiments in a row: 300 s at 0 W, the 8.8 mW step of Table 1 for 900 s, then PI
      to 5 K.
    """
    if protocol == "pi_only":
        return [(0.0, "setpoint", 5.0)]
    if protocol == "paper":
        return [(0.0, "power", 0.0), (300.0, "power", 0.0088), (1200.0, "setpoint", 5.0)]
    if protocol != "identification":
        raise ValueError(f"unknown protocol {protocol!r}: identification, pi_only or paper")
    line = LINE_RAD_S
    nominal = [(200.0, "power", 0.0), (400.0, "power", 0.010), (400.0, "power", 0.030),
               (240.0, "power", lambda t: 0.020 + 0.015 * math.sin(line * t)),
               (240.0, "power", lambda t: 0.020 + 0.015 * math.sin(2.5 * t)),
               (800.0, "setpoint", 5.0), (500.0, "power", 0.110), (520.0, "power", 0.140), (500.0, "setpoint", 4.6)]
    scale = duration_s / sum(length for length, _, _ in nominal)
    schedule, start = [], 0.0
    for length, kind, value in nominal:
        schedule.append((start, kind, value))
        start += length * scale
    return schedule


def run_protocol(cryostat: LumpedCryostat, protocol: str, duration_s: float, seed: int) -> dict:
    """A record of ``protocol`` on ``cryostat``: cryod-log columns (``time_s``, ``T2_K``, ``T5_K``, ``heater_W``,
    ``setpoint_K``), sampled every 80 ms with white reading noise, the PI (0.4 W/K, 0.01 W/(K s), 0..0.25 W,
    integral held while the heater is at a bound) acting on each noisy T2 reading."""
    network = _Network(cryostat)
    state = _settled_state(network)
    generator = np.random.default_rng(seed)
    schedule = protocol_schedule(protocol, duration_s)
    rows = int(duration_s / PERIOD_S)
    columns = {name: np.empty(rows) for name in ("time_s", "T2_K", "T5_K", "heater_W", "setpoint_K")}
    integral, segment = None, 0
    for row in range(rows):
        t = row * PERIOD_S
        while segment + 1 < len(schedule) and schedule[segment + 1][0] <= t:
            segment, integral = segment + 1, None
        flange, stage = network.readings(t, state)
        flange += generator.normal(0.0, NOISE_K[0])
        stage += generator.normal(0.0, NOISE_K[1])
        _, kind, value = schedule[segment]
        if kind == "setpoint":
            error = value - flange
            if integral is None:              # bumpless: the integral starts at the power last applied
                integral = network.history_p[-1] - PI_GAINS[0] * error
            wanted = PI_GAINS[0] * error + integral
            power = min(max(wanted, 0.0), HEATER_MAX_W)
            if power == wanted:
                integral += PI_GAINS[1] * error * PERIOD_S
            setpoint = value
        else:
            power, setpoint = float(value(t) if callable(value) else value), math.nan
        network.write(t, power)
        columns["time_s"][row], columns["T2_K"][row], columns["T5_K"][row] = t, flange, stage
        columns["heater_W"][row], columns["setpoint_K"][row] = power, setpoint
        state = network.advance(t, state, power, PERIOD_S)
    return columns


__all__ = ["Effects", "LumpedCryostat", "copper_heat_capacity", "protocol_schedule", "run_protocol"]
