"""Alarms: conditions the lab wants to hear about that do not stop regulation.

A fault switches the heater off (:mod:`cryod.service.faults`); an alarm never
touches the heater. It is raised when its condition has held for its delay,
cleared when the condition is over (or, latching, when acknowledged), and each
change is said in the journal, the record, the metrics and the status
(:mod:`cryod.service.alarms`).

:mod:`cryod.alarms.settings` reads the ``alarms`` section of the configuration;
:mod:`cryod.alarms.conditions` computes each alarm's figure from the loop's rows;
:mod:`cryod.alarms.latch` turns a condition into raised, cleared, latched and
acknowledged; :mod:`cryod.alarms.board` puts them together.
"""
