"""The interfaces process: the web page, the Lake Shore 336 command set, the metrics and the alarm hooks.

Started by the daemon (:mod:`cryod.service.interfaces_process`) as ``python -m cryod.interfaces``,
in a process of its own, so that nothing a client or a hook does can delay a tick of the loop. It
reads the daemon through the control socket's live stream (:mod:`cryod.service.stream`) and sends
its clients' commands through the control socket (:mod:`cryod.interfaces.daemon_link`); every
server runs on one asyncio event loop (:mod:`cryod.interfaces.process`), the alarm hooks on a
thread of their own.
"""
