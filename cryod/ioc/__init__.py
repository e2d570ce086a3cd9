"""cryod on EPICS: ``cryod ioc``, an IOC that serves the daemon's readings, settings and alarms as PVs.

The IOC is a process of its own (``cryod-ioc.service``), built on pythonSoftIOC (``softioc``, which
embeds EPICS base through ``epicscorelibs``: Channel Access and pvAccess, records, access
security). It is a client of the daemon's control socket like the interfaces process: the
daemon's live stream in (:class:`~cryod.interfaces.daemon_link.DaemonLink` into a
:class:`~cryod.interfaces.mirror.DaemonMirror`), commands out, relayed with the EPICS client's
identity. The daemon never imports it, and nothing it does can hold a tick.

- :mod:`cryod.ioc.pv_table`: every PV, its record type, unit and meaning (the docs' table);
- :mod:`cryod.ioc.readings`: each reading's value from the daemon's rows and status;
- :mod:`cryod.ioc.alarm_severity`: cryod's alarms as EPICS severities and STAT on the PVs they concern;
- :mod:`cryod.ioc.records`: the records themselves (softioc), updated with the daemon's sample instants;
- :mod:`cryod.ioc.settings`: puts to the writable PVs as the daemon's commands, refusals in EPICS terms,
  a put with completion on SETPOINT that ends when STABLE;
- :mod:`cryod.ioc.client_identity`: who put (the CA or PVA client's user and host);
- :mod:`cryod.ioc.access_security`: who may write (``ioc.writable``, the lab's access security file);
- :mod:`cryod.ioc.process`: ``cryod ioc``'s run.
"""
