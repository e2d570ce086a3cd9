"""What the fuzz tests of the control socket and the network interfaces share.

Numbers as text of every kind (what Python's ``float`` takes and the lab does not, other scripts'
digits and spaces), and the check that the daemon keeps every configured limit whatever it was sent.
"""

from hypothesis import strategies as st

NUMBER_TEXTS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=-1.0, max_value=25.0).map(lambda value: f"{value:.6g}"),
    st.integers(min_value=-10**30, max_value=10**30).map(str),
    st.sampled_from(["1_5", "nan", "inf", "-inf", "Infinity", "\u0665", "\uff15", "1e999", "-0", ".5", "5.",
                     "0x10", "1,5", "+", "", "on", "off", "status", "\u00a05", "5\u2003"]),
)


def limits_kept(daemon) -> bool:
    control, regulator = daemon.loop.config.control, daemon.loop.regulator
    return (control.setpoint_min_K <= regulator.ramp.target_K <= control.setpoint_max_K
            and 0.0 <= regulator.ramp.rate_K_per_min <= control.max_ramp_K_per_min
            and 0.0 <= regulator.manual_power_w <= daemon.config.heater.max_power_w)
