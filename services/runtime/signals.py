"""The one stop-signal helper: nodes, the service runner, the launcher and the standalone
tools (LIMO emulator, fake MAVLink vehicle, fault-drill agents) stop on SIGINT and SIGTERM
the same way, by setting a flag their own loop watches."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def catch_stop_signals(handler: Callable[[str], None]) -> Callable[[], None]:
    """Call ``handler(signal name)`` on SIGINT and SIGTERM; returns a function that puts the
    previous handlers back. Python installs handlers only on the main thread, so elsewhere
    (a node run by a test thread) nothing is installed and the stop comes from ``stop()``."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    old = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    for sig in STOP_SIGNALS:
        signal.signal(sig, lambda signum, _frame: handler(signal.Signals(signum).name))

    def restore() -> None:
        for sig, h in old.items():
            signal.signal(sig, h)

    return restore


def stop_event() -> threading.Event:
    """An event set by SIGINT or SIGTERM, for the whole life of a tool's process."""
    stop = threading.Event()
    catch_stop_signals(lambda _name: stop.set())
    return stop
