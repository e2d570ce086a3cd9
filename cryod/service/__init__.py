"""Service glue: systemd notification, the control socket, signals."""
