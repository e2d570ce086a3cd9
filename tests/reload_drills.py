"""Reloads handed to a daemon running in process on virtual time, and their answers.

:class:`ReloadDrill` hands operator commands and reloads of the example configuration to the loop
at given rows; :func:`reloads_over_the_socket` changes the file and asks for a reload the way an
operator does, with ``cryod ctl reload`` from a client thread.
"""

import threading
import time

from cryod.config import load_config
from cryod.model import load_model
from cryod.records.columns import Row
from cryod.records.record import read_record
from drivers.clock import VirtualClock
from cryod.service.commands import Command
from cryod.service.control_socket import send_command
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from cryod.service.simulation import SimulatedInstrumentsOpener
from tests.example_config import EXAMPLE, config_file, in_tmp, line_of
from tests.fault_drills import FaultDrill


def edited(replacements) -> str:
    text = EXAMPLE
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    return text


class ReloadDrill:
    """The daemon on the example configuration at ``path``; ``actions[n](drill)`` runs after row n, on the loop's
    thread, and may hand commands to the loop (:meth:`command`, :meth:`reload`); their answers are kept."""

    def __init__(self, tmp_path, actions, start=()):
        self.tmp_path = tmp_path
        self.path = config_file(tmp_path, edited(start))
        self.actions = dict(actions)
        self.opener = SimulatedInstrumentsOpener(load_model(), seed=4)
        self.rows = []
        self.sent: dict[str, Command] = {}
        self.daemon = Daemon(in_tmp(load_config(self.path), tmp_path), self.opener, VirtualClock(),
                             notifier=SystemdNotifier({}), row_taps=[self.tap], install_signal_handlers=False)

    def tap(self, item):
        if isinstance(item, Row):
            self.rows.append(item)
            action = self.actions.pop(len(self.rows), None)
            if action is not None:
                action(self)

    @property
    def loop(self):
        return self.daemon.loop

    def command(self, label, name, value=None):
        self.sent[label] = self.loop.submit(Command(name, value))

    def reload(self, label, replacements):
        """Write the file with ``replacements`` and hand the configuration read from it to the loop."""
        text = edited(replacements)
        config_file(self.tmp_path, text)
        self.sent[label] = self.loop.submit(Command("reload", in_tmp(load_config(self.path), self.tmp_path)))
        self.text = text

    def run(self, duration_s):
        self.result = self.daemon.run(duration_s)
        self.record = read_record(self.result.log_paths[0])
        return self.result

    def answer(self, label):
        command = self.sent[label]
        assert command.done.is_set(), label
        return command

    def refusal_at(self, label, key, fragment):
        """The reload ``label`` was refused at ``key``, with file and line, and ``fragment`` in its reason."""
        answer = self.answer(label)
        assert not answer.ok, answer.message
        located = f"kept the running configuration: {self.path}:{line_of(self.text, key.split('.')[-1] + ':')}: {key}: "
        assert answer.message.startswith(located), answer.message
        assert fragment in answer.message, answer.message
        return answer.message


def daemon_from_file(tmp_path, path, row_actions, reload_config=None):
    """The daemon on the configuration read from ``path`` (data and socket moved into tmp_path);
    ``row_actions[n](daemon)`` runs after the n-th row, on the loop's thread."""
    config = in_tmp(load_config(path), tmp_path)
    drill = FaultDrill(tmp_path, {}, config=config)
    rows = []
    answers = []

    def tap(item):
        if isinstance(item, Row):
            rows.append(item)
            action = row_actions.get(len(rows))
            if action is not None:
                answers.append(action(daemon))
    daemon = Daemon(config, drill.open_instruments, VirtualClock(), notifier=SystemdNotifier({}), row_taps=[tap],
                    install_signal_handlers=False, reload_config=reload_config)
    return daemon, answers


def reloads_over_the_socket(tmp_path, path, first, second):
    """The daemon on the file at ``path``: ``first()`` changes the file after row 100 and ``second()`` after row
    400, each followed by ``cryod ctl reload`` from a client thread; the loop ticks slowly until the client has
    its answer. Returns the daemon, its result and the two replies."""
    replies = {}
    asking = []

    def reload_over_the_socket(name, change):
        def action(daemon):
            change()
            asking.append(threading.Thread(target=lambda: replies.update(
                {name: send_command(tmp_path / "control.sock", "reload", timeout_s=20.0)})))
            asking[-1].start()
        return action

    def until_answered(name):
        def action(daemon):          # the loop keeps ticking, slowly, until the client has its answer
            if name not in replies:
                time.sleep(0.002)
        return action

    actions = {row: until_answered("first") for row in range(101, 390)}
    actions.update({row: until_answered("second") for row in range(401, 740)})
    actions[100] = reload_over_the_socket("first", first)
    actions[400] = reload_over_the_socket("second", second)
    daemon, _ = daemon_from_file(tmp_path, path, actions, reload_config=lambda: in_tmp(load_config(path), tmp_path))
    result = daemon.run(60.0)
    for thread in asking:
        thread.join(20.0)
    return daemon, result, (replies.get("first"), replies.get("second"))
