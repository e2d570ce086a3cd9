# The EPICS Archiver Appliance's policies for cryod's IOC: a fragment of the appliance's policies.py
# (its archappl.properties names the file). Merge cryod_policy into the lab's determinePolicy, as below.
# The PVs themselves are added with the appliance's archivePV call and cryod-pvs.json beside this file:
#
#   sed 's/CRYO1:/CRYO2:/' cryod-pvs.json > /tmp/pvs.json          # the lab's ioc.prefix
#   curl -H 'Content-Type: application/json' -d @/tmp/pvs.json http://archiver:17665/mgmt/bpl/archivePV
#
# cryod's IOC stamps every reading with the daemon's own sample instant, so the archive holds the
# readings at the times they were taken (docs/how-to/epics-bluesky.md, "EPICS and Bluesky").

# The ioc.prefix of each of the lab's cryostats.
CRYOD_PREFIXES = ("CRYO1:",)
# Every PV of cryod's IOC after its prefix (docs/reference/epics-pvs.md).
CRYOD_PVS = ("T2", "T5", "T2_AVG", "HEATER", "HEATER_PI", "HEATER_FF", "HEATER_MEAN", "HEATER_MAX", "LINE",
             "LINE_LIMIT", "LINE_LIMIT_FROM", "FEEDFORWARD_LOCKED", "FEEDFORWARD_SCALE", "SETPOINT_RBV",
             "SETPOINT_IN_USE", "RAMPING", "RAMP_RBV", "STATE", "STABLE", "STABLE_FOR", "STABLE_TOL",
             "STABLE_HOLD", "ZONE", "LAST_FAULT", "SETPOINT_WARNING", "ALARMS", "RECORD_PATH", "LATENESS",
             "LATENESS_P99", "LATENESS_MAX", "TICKS", "OVERRUNS", "CONNECTED", "MESSAGE", "SETPOINT", "RAMP",
             "FEEDFORWARD", "HEATER_OFF", "NOTE", "ALARM_ACK")
# Readings that change at every tick of the 80 ms loop: every value kept.
CRYOD_EVERY_TICK = ("T2", "T5", "HEATER", "HEATER_PI", "HEATER_FF", "SETPOINT_IN_USE", "LATENESS")


def cryod_policy(pvInfo):
    """The policy of one of cryod's PVs (None for others): every change, at the loop's rate for the readings
    taken each tick, at most once a second for the rest."""
    name = pvInfo["pvName"]
    prefix = next((prefix for prefix in CRYOD_PREFIXES if name.startswith(prefix)), None)
    suffix = None if prefix is None else name[len(prefix):]
    if suffix not in CRYOD_PVS:
        return None
    fast = suffix in CRYOD_EVERY_TICK
    return {
        "samplingPeriod": 0.08 if fast else 1.0,
        "samplingMethod": "MONITOR",
        "dataStores": ["pb://localhost?name=STS&rootFolder=${ARCHAPPL_SHORT_TERM_FOLDER}&partitionGranularity=PARTITION_HOUR&consolidateOnShutdown=true",
                       "pb://localhost?name=MTS&rootFolder=${ARCHAPPL_MEDIUM_TERM_FOLDER}&partitionGranularity=PARTITION_DAY&hold=2&gather=1",
                       "pb://localhost?name=LTS&rootFolder=${ARCHAPPL_LONG_TERM_FOLDER}&partitionGranularity=PARTITION_YEAR"],
        "policyName": "cryod-every-tick" if fast else "cryod",
    }


def determinePolicy(pvInfo):
    """The appliance's entry point: cryod's PVs by cryod_policy, the lab's others by its own rules (here the
    appliance's default, a SCAN of one a second)."""
    policy = cryod_policy(pvInfo)
    if policy is not None:
        return policy
    return {
        "samplingPeriod": 1.0,
        "samplingMethod": "SCAN",
        "dataStores": ["pb://localhost?name=STS&rootFolder=${ARCHAPPL_SHORT_TERM_FOLDER}&partitionGranularity=PARTITION_HOUR&consolidateOnShutdown=true",
                       "pb://localhost?name=MTS&rootFolder=${ARCHAPPL_MEDIUM_TERM_FOLDER}&partitionGranularity=PARTITION_DAY&hold=2&gather=1",
                       "pb://localhost?name=LTS&rootFolder=${ARCHAPPL_LONG_TERM_FOLDER}&partitionGranularity=PARTITION_YEAR"],
        "policyName": "default",
    }
