"""Control: the PI loop on the flange temperature and the setpoint ramp."""
