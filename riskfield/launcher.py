"""``riskfield up``: the router and a set of services, each in its own fresh interpreter.

Children are started as new processes that exec a new Python (the spawn model: nothing is
inherited from a parent that may hold a Zenoh session, which must never be forked). Each
child's output is prefixed with its service name. Ctrl-C or SIGTERM stops them all; if one
dies on its own, the rest are stopped and the exit code is non-zero.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

from rich.console import Console
from rich.text import Text

from riskfield.services.runtime.signals import catch_stop_signals

COLOURS = ["cyan", "magenta", "green", "yellow", "blue", "bright_red", "bright_cyan", "bright_magenta"]


@dataclass
class Child:
    name: str
    argv: list[str]
    colour: str
    proc: subprocess.Popen | None = None
    reader: threading.Thread | None = None
    lines: list[str] = field(default_factory=list)


class Launcher:
    def __init__(self, console: Console | None = None, env: dict[str, str] | None = None,
                 log_path: str | os.PathLike | None = None, echo: bool = True):
        self.console = console or Console(stderr=True, highlight=False, soft_wrap=True)
        self.echo = echo
        self._log = open(log_path, "a", buffering=1) if log_path else None  # closed in stop()
        self._log_lock = threading.Lock()
        self.children: list[Child] = []
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self._stopping = threading.Event()
        self.failed: str | None = None

    def add(self, name: str, args: Sequence[str], label: str | None = None) -> None:
        argv = [sys.executable, "-m", "riskfield", "run", name, *args]
        self.children.append(Child(label or name, argv, COLOURS[len(self.children) % len(COLOURS)]))

    def _pump(self, child: Child) -> None:
        assert child.proc is not None and child.proc.stdout is not None
        width = max(len(c.name) for c in self.children)
        for raw in child.proc.stdout:
            line = raw.decode(errors="replace").rstrip("\n")
            if self._log is not None:
                with self._log_lock:
                    self._log.write(f"{child.name:<{width}} | {line}\n")
            if self.echo:
                text = Text(f"{child.name:<{width}} | ", style=child.colour)
                text.append(line)
                self.console.print(text)

    def start(self) -> None:
        for child in self.children:
            child.proc = subprocess.Popen(
                child.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=self.env,
                start_new_session=True,  # signals come from us, not from the terminal's Ctrl-C
            )
            child.reader = threading.Thread(target=self._pump, args=(child,), daemon=True)
            child.reader.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stopping.set()
        for child in reversed(self.children):  # services first, router last
            if child.proc and child.proc.poll() is None:
                child.proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for child in self.children:
            if child.proc is None:
                continue
            try:
                child.proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.console.print(f"[red]{child.name} did not stop in time; killing it[/red]")
                child.proc.kill()
                child.proc.wait()
        for child in self.children:
            if child.reader:
                child.reader.join(timeout=2)
        if self._log is not None:
            self._log.close()
            self._log = None

    def dead(self) -> list[Child]:
        """Children that have exited."""
        return [c for c in self.children if c.proc is not None and c.proc.poll() is not None]

    def child(self, label: str) -> Child:
        return next(c for c in self.children if c.name == label)

    def stop_one(self, label: str, timeout_s: float = 10.0) -> int | None:
        """Stop one child (SIGINT, then SIGKILL after ``timeout_s``); its exit code."""
        c = self.child(label)
        if c.proc is None:
            return None
        if c.proc.poll() is None:
            c.proc.send_signal(signal.SIGINT)
            try:
                c.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()
        return c.proc.returncode

    def wait(self, duration_s: float | None = None) -> int:
        """Block until a signal, ``duration_s``, or a child's death; stop all; exit code."""
        stop_signal = threading.Event()
        restore = catch_stop_signals(lambda _name: stop_signal.set())
        end = None if duration_s is None else time.monotonic() + duration_s
        try:
            while not stop_signal.is_set() and (end is None or time.monotonic() < end):
                for child in self.children:
                    if child.proc is not None and child.proc.poll() is not None:
                        self.failed = f"{child.name} exited with code {child.proc.returncode}"
                        break
                if self.failed:
                    self.console.print(f"[bold red]{self.failed}; stopping the stack[/bold red]")
                    break
                time.sleep(0.1)
        finally:
            self.stop()
            restore()
        if self.failed:
            return 1
        bad = [c for c in self.children if c.proc is not None and c.proc.returncode not in (0, -signal.SIGINT)]
        for c in bad:
            self.console.print(f"[red]{c.name} ended with code {c.proc.returncode if c.proc else '?'}[/red]")
        return 1 if bad else 0
