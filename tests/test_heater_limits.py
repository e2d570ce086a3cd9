"""Every heater can reach its own maximum: one rounding rule for the regulator's limit and the driver's check."""

import dataclasses
import math

import numpy as np
import pytest

from cryod.config import HeaterConfig
from drivers.clock import VirtualClock
from drivers.errors import HeaterLimitRefused
from drivers.heater_limits import current_for_power_a, largest_power_w
from drivers.keithley2400 import Keithley2400
from drivers.keithley6221 import Keithley6221
from simulated_hw.bench import SimulatedBench
from tests.example_config import simulated_config
from tests.fault_drills import FaultDrill

#: E24 resistances over six decades (1 ohm to 910 kohm: heaters are 10 ohm to some kohm) and currents of
#: 0.5 to 105 mA in 0.5 mA steps.
E24 = (1.0, 1.1, 1.2, 1.3, 1.5, 1.6, 1.8, 2.0, 2.2, 2.4, 2.7, 3.0, 3.3, 3.6, 3.9, 4.3, 4.7, 5.1, 5.6, 6.2, 6.8, 7.5,
       8.2, 9.1)
RESISTANCES_OHM = [round(value * 10 ** decade, 6) for decade in range(6) for value in E24] + [25.0, 50.0, 75.0]
CURRENTS_A = [round(k * 5e-4, 7) for k in range(1, 211)]


def test_the_largest_power_is_taken_and_a_float_step_more_is_refused_over_a_grid_of_heaters():
    """R * I_max**2 needs one floating-point step too much current for a share of common heaters (75 ohm at
    30 mA); the limit the regulator uses is the largest power the driver's own test accepts, no further."""
    resistance = np.repeat(RESISTANCES_OHM, len(CURRENTS_A))
    current = np.tile(CURRENTS_A, len(RESISTANCES_OHM))
    naive_refused = 0
    for r, i in zip(resistance.tolist(), current.tolist()):
        naive_refused += current_for_power_a(r * i ** 2, r) > i
        limit = largest_power_w(r, i)
        assert current_for_power_a(limit, r) <= i, (r, i)
        assert current_for_power_a(math.nextafter(limit, math.inf), r) > i, (r, i)
        assert limit == pytest.approx(r * i * i, rel=1e-15)
    assert resistance.size > 30000 and naive_refused > 500      # the rounding the rule is there for


@pytest.mark.parametrize("resistance_ohm, max_current_a", [(75.0, 0.03), (50.0, 0.071), (25.0, 0.103)])
@pytest.mark.parametrize("driver, supply", [(Keithley6221, "6221"), (Keithley2400, "2400")])
def test_the_drivers_take_the_configured_maximum_and_refuse_real_excess(resistance_ohm, max_current_a, driver,
                                                                         supply):
    clock = VirtualClock()
    bench = SimulatedBench(clock, heater_resistance_ohm=resistance_ohm, supply=supply, noise=False)
    heater = driver(bench.in_process_transports().heater_supply, clock, resistance_ohm, max_current_a=max_current_a,
                    voltage_compliance_v=10.0)
    maximum = HeaterConfig(resistance_ohm, max_current_a, 10.0).max_power_w
    assert maximum == heater.max_power_w
    assert heater.set_power_w(maximum).current_a <= max_current_a
    assert bench.heater_supply.heater_power_w == pytest.approx(maximum, rel=1e-6)
    for excess in (maximum * (1 + 1e-9), maximum * 1.01, resistance_ohm * (max_current_a + 1e-6) ** 2):
        with pytest.raises(HeaterLimitRefused, match="above the"):
            heater.set_power_w(excess)
    heater.close()


def test_a_75_ohm_30_mA_heater_regulates_at_its_maximum(tmp_path):
    """A setpoint the heater cannot reach holds it at its maximum: the supply must take that power."""
    config = simulated_config(tmp_path, setpoint_K=19.0)
    config = dataclasses.replace(config, heater=HeaterConfig(75.0, 0.03, 10.0))
    drill = FaultDrill(tmp_path, {}, config=config)
    assert drill.run(20.0).exit_code == 0
    limited = drill.record.heater_w[np.array(drill.states) == "closed-limited"]
    assert limited.size > 100 and limited.max() == pytest.approx(config.heater.max_power_w, rel=1e-6)
    assert drill.opener.bench.heater_supply.current_setpoint_a == 0.0        # off at the end, not refused
