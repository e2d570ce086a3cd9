"""A daemon client whose statuses come from a list, for the client's waits without a daemon."""

import cryod


class ScriptedDaemon(cryod.DaemonClient):
    """A client whose status comes from a list (the daemon's clock in time_s)."""

    def __init__(self, statuses):
        self.statuses = iter(statuses)
        self.socket = "scripted"
        self.timeout_s = 1.0

    def status(self):
        return next(self.statuses)
