"""Services as processes: the one process runner, and the client-side helpers around it.

Used by ``riskfield up``, ``riskfield demo``, the experiments' stack and the test helpers (``riskfield/testing.py``).

* **Spawn model.** A Zenoh session must never be forked once open (its runtime threads do not
  survive a ``fork``), so every service starts as a *new interpreter*
  (``python -m riskfield run SERVICE ...``) through ``subprocess``, never ``multiprocessing``.
  The runner itself may hold a session (readiness checks, an embedded router): ``subprocess``
  execs the child straight after the fork, before any Python code runs in it.
* **Logs.** Each child's stdout and stderr go through one pipe; a reader thread keeps the tail
  in memory (``Child.output``) and, as asked, writes each line prefixed with the child's label
  to a log file and/or echoes it (coloured) to the console.
* **Stop.** SIGINT (a service's clean stop), then SIGTERM, then SIGKILL, each with a bounded
  wait; services first, routers last, so nobody loses its router while closing.
* **Readiness.** A service is ready when its liveliness token ``{prefix}/{robot}/alive/{service}``
  is visible (declared by ``Node`` once its session is open).
* **Supervision.** ``watch`` (``riskfield up``) restarts a child that crashed (any exit but a
  clean one, ``CLEAN_EXIT``, or a configuration error, ``NO_RESTART_CODES``) after an
  exponential back-off, bounded by ``RestartPolicy.backoff_max_s`` and reset once the child has
  run ``healthy_s``; each crash is one log line. The other children keep running: a crashed
  perception must not take the safety filter (and its brake) down with it. A child that crashes
  ``max_restarts`` times in a row without a healthy run in between has exhausted its budget: the
  stack stops and ``watch`` returns 1, so an outer supervisor (systemd, compose) takes over.
  ``RestartPolicy(enabled=False)`` (``riskfield up --no-restart``) is the fail-fast mode for tests
  and CI: the stack stops as soon as a *required* child exits by itself.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import zenoh

from riskfield.protocol import Keys

from .router import RouterSettings
from .session import open_session, zenoh_config
from .settings import NodeSettings
from .signals import catch_stop_signals

if TYPE_CHECKING:
    from rich.console import Console

#: What a clean stop looks like: the service's own exit code 0, or death by our SIGINT.
CLEAN_EXIT = (0, -signal.SIGINT)
#: Lines of output each child keeps in memory (its log file, if any, has all of them).
OUTPUT_LINES = 20000
#: Exit codes that a restart cannot fix: 2 is the CLI's code for a bad configuration or usage
#: (systemd's ``RestartPreventExitStatus=2`` in ``deploy/robot`` says the same).
NO_RESTART_CODES = (2,)
COLOURS = ("cyan", "magenta", "green", "yellow", "blue", "bright_red", "bright_cyan", "bright_magenta")


# -- client side ------------------------------------------------------------------------------


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nobody listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0, period_s: float = 0.02) -> bool:
    """Poll ``predicate`` until it holds or ``timeout_s`` passes (bounded, never infinite)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period_s)  # the poll period; the predicate decides
    return bool(predicate())


def endpoint_settings(endpoint: str, mode: str = "client", timeout_s: float = 15.0) -> NodeSettings:
    """Node settings for a session on ``endpoint`` only: a router listens on it, anything else
    dials it. Built without reading files or ``RISKFIELD_*`` variables (a tool's session must
    not pick up the settings meant for a service)."""
    router = mode == "router"
    return NodeSettings.model_construct(mode=mode, connect=[] if router else [endpoint],
                                        listen=[endpoint] if router else [], connect_timeout_s=timeout_s)


def router_settings(endpoint: str, connect: Sequence[str] = (), timeout_s: float = 15.0) -> RouterSettings:
    """``riskfield run router``'s settings for a router listening on ``endpoint`` and dialling ``connect``,
    built as ``endpoint_settings`` builds a tool's (no files, no ``RISKFIELD_*`` variables)."""
    return RouterSettings.model_construct(listen=[endpoint], connect=list(connect), connect_timeout_s=timeout_s)


@contextlib.contextmanager
def client_session(endpoint: str, timeout_s: float = 15.0) -> Iterator[zenoh.Session]:
    """A client session to ``endpoint``, retried while a router process is still starting."""
    try:
        session = open_session(endpoint_settings(endpoint, timeout_s=timeout_s))
    except ConnectionError as exc:
        raise TimeoutError(f"no Zenoh router at {endpoint} after {timeout_s} s") from exc
    try:
        yield session
    finally:
        session.close()


def alive_services(session: zenoh.Session, key_expr: str, timeout_s: float = 0.5) -> set[str]:
    """The keys of the liveliness tokens matching ``key_expr`` visible now."""
    return {str(r.ok.key_expr) for r in session.liveliness().get(key_expr, timeout=timeout_s) if r.ok is not None}


def wait_alive(session: zenoh.Session, key: str, timeout_s: float = 20.0) -> bool:
    """Wait until a liveliness token on ``key`` is visible (a node is up and connected)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if alive_services(session, key):
            return True
        time.sleep(0.1)  # poll period of the liveliness query
    return False


class EmbeddedRouter:
    """A Zenoh router session in this process, on a loopback port (free unless given): what
    ``riskfield run router`` runs, without a process of its own. Use as a context manager."""

    def __init__(self, port: int | None = None):
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.session: zenoh.Session | None = None

    def __enter__(self) -> EmbeddedRouter:
        self.session = zenoh.open(zenoh_config(router_settings(self.endpoint)))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None


# -- processes ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class RestartPolicy:
    r"""How ``ProcessRunner.watch`` treats a child that crashed.

    The n-th restart in a row waits :math:`\min(b_{max}, b_0 2^{n-1})`; a child that has
    run ``healthy_s`` since its last start is healthy again (back-off and budget reset). After
    ``max_restarts`` restarts in a row (0: no limit) the next crash stops the stack.
    """

    enabled: bool = True
    backoff_s: float = 0.5
    backoff_max_s: float = 30.0
    healthy_s: float = 30.0
    max_restarts: int = 10

    def __post_init__(self) -> None:
        if not (0 < self.backoff_s <= self.backoff_max_s) or self.healthy_s <= 0 or self.max_restarts < 0:
            raise ValueError(f"bad restart policy {self}: need 0 < backoff_s <= backoff_max_s, healthy_s > 0, "
                             "max_restarts >= 0")

    def delay(self, attempt: int) -> float:
        """Back-off before restart number ``attempt`` (1-based) of a streak."""
        return min(self.backoff_max_s, self.backoff_s * 2.0 ** max(0, attempt - 1))


#: Fail-fast: no restarts, the stack stops when a required child exits.
NO_RESTART = RestartPolicy(enabled=False)


def describe_exit(code: int | None) -> str:
    """``code 1`` or ``signal SIGKILL`` for a ``Popen.returncode``."""
    if code is not None and code < 0:
        with contextlib.suppress(ValueError):
            return f"signal {signal.Signals(-code).name}"
    return f"code {code}"


def service_argv(service: str, args: Sequence[str] = ()) -> list[str]:
    """The command line of one service in a fresh interpreter of this Python."""
    return [sys.executable, "-m", "riskfield", "run", service, *map(str, args)]


class Child:
    """One service process: started with ``start``, stopped with ``stop``; output kept."""

    def __init__(self, label: str, service: str, argv: Sequence[str], *, env: dict[str, str] | None = None,
                 required: bool = True, on_line: Callable[[Child, str], None] | None = None):
        self.label = label
        self.service = service
        self.argv = list(argv)
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.required = required
        self.proc: subprocess.Popen | None = None
        self._on_line = on_line
        self._lines: deque[str] = deque(maxlen=OUTPUT_LINES)
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None
        self.started_at = 0.0  # time.monotonic() of the last start
        self.restarts = 0  # restarts since the first start
        self.streak = 0  # restarts in a row without a healthy run between them
        self.restart_at: float | None = None  # when a pending restart is due (time.monotonic())
        self.pids: list[int] = []  # one per start, oldest first
        self.last_line = ""  # the last line printed (what a node that is starting says it is doing)
        self.last_line_at = 0.0  # its time.monotonic()

    def start(self) -> Child:
        if self.proc is not None:
            raise RuntimeError(f"{self.label} was started already")
        self.started_at = self.last_line_at = time.monotonic()
        self.proc = subprocess.Popen(
            self.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=self.env,
            start_new_session=True,  # a terminal's Ctrl-C reaches us only; we stop children in order
        )
        self.pids.append(self.proc.pid)
        self._reader = threading.Thread(target=self._pump, name=f"output:{self.label}", daemon=True)
        self._reader.start()
        return self

    def restart(self) -> Child:
        """Start again after the process ended by itself (its earlier output is kept)."""
        if self.alive():
            raise RuntimeError(f"{self.label} is still running")
        self.join_output()
        self.proc = None
        self.restart_at = None
        self.restarts += 1
        return self.start()

    def _pump(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = raw.decode(errors="replace").rstrip("\n")
            with self._lock:
                self._lines.append(line)
                self.last_line, self.last_line_at = line, time.monotonic()
            if self._on_line is not None:
                self._on_line(self, line)

    @property
    def output(self) -> str:
        """Everything the process printed so far (the last ``OUTPUT_LINES`` lines)."""
        with self._lock:
            return "".join(line + "\n" for line in self._lines)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    @property
    def returncode(self) -> int | None:
        return None if self.proc is None else self.proc.poll()

    def stop(self, first: int = signal.SIGINT, timeout_s: float = 10.0, term_s: float = 3.0) -> tuple[int | None, str]:
        """Stop the process: ``first`` (SIGINT: the services' clean stop), then SIGTERM after
        ``timeout_s``, then SIGKILL after ``term_s`` more. Returns the exit code and the signal
        that had to follow ``first`` (``""`` when none was needed)."""
        if self.proc is None:
            return None, ""
        escalated = ""
        if self.proc.poll() is None:
            plan: list[tuple[int, float | None]] = [(first, timeout_s)]
            if first != signal.SIGTERM:
                plan.append((signal.SIGTERM, term_s))
            plan.append((signal.SIGKILL, None))
            for i, (sig, wait_s) in enumerate(plan):
                with contextlib.suppress(ProcessLookupError):
                    self.proc.send_signal(sig)
                try:
                    self.proc.wait(wait_s)
                except subprocess.TimeoutExpired:
                    continue
                escalated = signal.Signals(sig).name if i else ""
                break
        self.join_output()
        return self.proc.returncode, escalated

    def join_output(self, timeout_s: float = 2.0) -> None:
        """Wait for the reader to drain the pipe (the process has ended)."""
        if self._reader is not None:
            self._reader.join(timeout_s)


class ProcessRunner:
    """A set of service processes, started in order and stopped in reverse (routers last).

    ``endpoint`` is the router's endpoint: a ``router`` child listens on it, every other service
    dials it. ``keys`` names the robot whose liveliness tokens tell readiness (the children's own
    ``--robot``/``--prefix`` are up to the caller's arguments).
    ``log_path`` gets every child's lines prefixed with its label; ``echo`` prints them too.
    """

    def __init__(self, endpoint: str, keys: Keys | None = None, *, env: dict[str, str] | None = None,
                 log_path: str | os.PathLike | None = None, echo: bool = False, console: Console | None = None,
                 stop_timeout_s: float = 10.0, restart: RestartPolicy = NO_RESTART):
        self.endpoint = endpoint
        self.restart = restart
        self.keys = keys or Keys()
        self.env = dict(env or {})
        self.echo = echo
        self.stop_timeout_s = stop_timeout_s
        self.children: dict[str, Child] = {}
        self.failed: str | None = None
        self._console = console
        self._log = open(log_path, "a", buffering=1) if log_path else None  # closed in close()
        self._out_lock = threading.Lock()
        self._stop_requested = threading.Event()

    # -- building ---------------------------------------------------------------------------------
    def add(self, label: str, service: str | None = None, args: Sequence[str] = (), *, required: bool = True,
            env: dict[str, str] | None = None) -> Child:
        """Declare a child (not started): ``riskfield run SERVICE`` on this runner's router and
        robot, plus ``args``."""
        service = service or label
        if label in self.children and self.children[label].alive():
            raise ValueError(f"{label!r} is running already")
        flag = "--listen" if service == "router" else "--connect"
        child = Child(label, service, service_argv(service, [flag, self.endpoint, *args]),
                      env={**self.env, **(env or {})}, required=required, on_line=self._line)
        self.children[label] = child
        return child

    def start(self, label: str | None = None) -> None:
        """Start one declared child, or all not started yet, in declaration order."""
        for child in ([self.children[label]] if label else list(self.children.values())):
            if child.proc is None:
                child.start()

    def spawn(self, label: str, service: str | None = None, args: Sequence[str] = (), *, session:
              zenoh.Session | None = None, timeout_s: float = 60.0, required: bool = True) -> Child:
        """``add`` + ``start``; with a ``session``, also wait until the service is alive (and stop it
        and raise if it is not within ``timeout_s``)."""
        child = self.add(label, service, args, required=required)
        child.start()
        if session is not None and not self.wait_ready(session, [label], timeout_s):
            out = child.output
            self.stop(label)
            raise RuntimeError(f"{label} ({child.service}) did not come up in {timeout_s} s:\n{out[-3000:]}")
        return child

    def _line(self, child: Child, line: str) -> None:
        width = max(map(len, tuple(self.children)))
        prefix = f"{child.label:<{width}} | "
        with self._out_lock:
            if self._log is not None:
                self._log.write(prefix + line + "\n")
            if self.echo:
                if self._console is None:
                    print(prefix + line, file=sys.stderr, flush=True)
                else:
                    from rich.text import Text

                    colour = COLOURS[tuple(self.children).index(child.label) % len(COLOURS)]
                    text = Text(prefix, style=colour)
                    text.append(line)
                    self._console.print(text)

    def _say(self, message: str, style: str = "") -> None:
        if self._console is not None:
            self._console.print(f"[{style}]{message}[/{style}]" if style else message)
        else:
            print(message, file=sys.stderr, flush=True)
        if self._log is not None:
            with self._out_lock:
                self._log.write(f"-- {message}\n")

    # -- state ------------------------------------------------------------------------------------
    def alive_key(self, label: str) -> str:
        return self.keys.alive(self.children[label].service)

    def ready(self, session: zenoh.Session, labels: Sequence[str] | None = None) -> set[str]:
        """The labels (of ``labels``, default all) whose service's liveliness token is visible."""
        seen = alive_services(session, self.keys.key("alive/*"))
        return {label for label in (labels or self.children) if self.alive_key(label) in seen}

    def wait_ready(self, session: zenoh.Session, labels: Sequence[str] | None = None, timeout_s: float = 60.0, *,
                   quiet_s: float | None = None, progress: Callable[[dict[str, Child], float], None] | None = None,
                   progress_every_s: float = 5.0) -> bool:
        """Wait until every child of ``labels`` (default all) is alive on the network; False after
        ``timeout_s`` or as soon as one of them exits. With ``quiet_s``, also False as soon as a child
        not alive yet has printed nothing for that long: a node that is starting says what it does
        every few seconds (``logs.StartupReport``: the kernel it compiles, say), so a long start goes
        on as long as it makes itself heard, up to ``timeout_s``. ``progress(late, elapsed)`` is called
        every ``progress_every_s`` with the children not alive yet."""
        want = list(labels or self.children)
        t0 = time.monotonic()
        end, told = t0 + timeout_s, t0
        while True:
            if any(self.children[label].returncode is not None for label in want):
                return False
            up = self.ready(session, want)
            if up == set(want):
                return True
            now = time.monotonic()
            late = {label: self.children[label] for label in want if label not in up}
            if now >= end:
                return False
            if quiet_s is not None and any(now - c.last_line_at > quiet_s for c in late.values()):
                return False
            if progress is not None and now - told >= progress_every_s:
                told = now
                progress(late, now - t0)
            time.sleep(0.1)  # poll period of the liveliness query

    def exited(self) -> list[Child]:
        """Children that have ended."""
        return [c for c in self.children.values() if c.returncode is not None]

    def ended_badly(self) -> list[str]:
        """Labels of children that ended with anything but a clean stop."""
        return [c.label for c in self.children.values() if c.returncode is not None and c.returncode not in CLEAN_EXIT]

    @staticmethod
    def _exit_message(child: Child) -> str:
        return f"{child.label} exited with code {child.returncode}"

    # -- stopping ---------------------------------------------------------------------------------
    def stop(self, label: str | None = None, timeout_s: float | None = None) -> int | None:
        """Stop one child (its exit code), or all of them: services first, routers last."""
        timeout = self.stop_timeout_s if timeout_s is None else timeout_s
        if label is not None:
            return self._stop_group([self.children[label]], timeout).get(label)
        running = [c for c in reversed(self.children.values()) if c.proc is not None]
        self._stop_group([c for c in running if c.service != "router"], timeout)
        self._stop_group([c for c in running if c.service == "router"], timeout)
        return None

    def _stop_group(self, children: list[Child], timeout_s: float) -> dict[str, int | None]:
        """Stop children in parallel (each one's escalation runs on its own thread)."""
        codes: dict[str, int | None] = {}

        def one(child: Child) -> None:
            code, how = child.stop(signal.SIGINT, timeout_s)
            codes[child.label] = code
            if how:
                self._say(f"{child.label} did not stop on SIGINT within {timeout_s:.0f} s; sent {how}", "red")

        threads = [threading.Thread(target=one, args=(c,), daemon=True) for c in children]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return codes

    def close(self) -> None:
        """Stop everything and close the log (idempotent)."""
        self.stop()
        with self._out_lock:
            if self._log is not None:
                self._log.close()
                self._log = None

    def __enter__(self) -> ProcessRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the ``riskfield up`` loop ----------------------------------------------------------------
    def request_stop(self) -> None:
        """Ask a running ``watch`` to stop everything and return (any thread)."""
        self._stop_requested.set()

    def _supervise(self, now: float) -> str | None:
        """One pass over the children: restart the crashed ones that are due, schedule the newly
        crashed, reset the back-off of the healthy. Returns why the stack must stop, if it must."""
        policy = self.restart
        for child in self.children.values():
            code = child.returncode
            if child.proc is None:
                continue
            if code is None:
                if child.streak and now - child.started_at >= policy.healthy_s:
                    child.streak = 0
                continue
            if child.restart_at is not None:
                if now >= child.restart_at:
                    child.restart()
                continue
            if code in CLEAN_EXIT and policy.enabled:
                continue  # it finished (or someone stopped it on purpose): on-failure does not restart
            if not policy.enabled:
                if child.required:
                    return self._exit_message(child)
                continue
            ran = now - child.started_at
            if ran >= policy.healthy_s:
                child.streak = 0  # it crashed after a healthy run (perhaps between two passes)
            if code in NO_RESTART_CODES:
                return f"{self._exit_message(child)} (a configuration error: not restarted)"
            if policy.max_restarts and child.streak >= policy.max_restarts:
                return (f"{child.label} exited with {describe_exit(code)} after {ran:.1f} s; restart budget "
                        f"exhausted ({child.streak} restarts in a row)")
            child.streak += 1
            delay = policy.delay(child.streak)
            child.restart_at = now + delay
            self._say(f"{child.label} exited with {describe_exit(code)} after {ran:.1f} s; restarting in "
                      f"{delay:.1f} s (restart {child.restarts + 1}, {child.streak} in a row)", "bold yellow")
        return None

    def watch(self, duration_s: float | None = None, ready_timeout_s: float | None = 60.0) -> int:
        """Start what is not started, then serve until SIGINT/SIGTERM, ``request_stop``,
        ``duration_s``, or a failure; stop everything. Crashed children are restarted as the
        runner's ``RestartPolicy`` says (see the module docstring).

        Exit code: 0 when asked to stop and everything stopped cleanly; 1 when something ended
        badly at that stop (a crashed child, even one waiting for its restart, or one that needed
        SIGTERM/SIGKILL counts by its last exit code), when a child exhausted its restart budget
        or exited with a configuration error, or (``NO_RESTART``) when a required child exited
        by itself. With ``ready_timeout_s``, says once when every service is alive on the network
        (or which are not, after that long)."""
        stop = self._stop_requested
        restore = catch_stop_signals(lambda _name: stop.set())
        end = None if duration_s is None else time.monotonic() + duration_s
        t0 = time.monotonic()
        pending = ready_timeout_s is not None
        session: zenoh.Session | None = None
        try:
            self.start()
            while not stop.is_set() and (end is None or time.monotonic() < end):
                failure = self._supervise(time.monotonic())
                if failure is not None:
                    self.failed = failure
                    self._say(f"{self.failed}; stopping the stack", "bold red")
                    break
                if pending:
                    session = session or _try_client(self.endpoint)
                    up = self.ready(session) if session is not None else set()
                    if len(up) == len(self.children):
                        self._say(f"ready in {time.monotonic() - t0:.1f} s: {', '.join(self.children)}", "green")
                        pending = False
                    elif ready_timeout_s is not None and time.monotonic() - t0 > ready_timeout_s:
                        late = [label for label in self.children if label not in up]
                        self._say(f"not alive after {ready_timeout_s:.0f} s: {', '.join(late)}", "yellow")
                        pending = False
                stop.wait(0.1)  # the supervision period (a signal or request_stop ends it at once)
        finally:
            if session is not None:
                session.close()
            self.close()
            restore()
        bad = self.ended_badly()
        for label in bad:
            if self.failed is None or not self.failed.startswith(f"{label} "):
                self._say(f"{label} ended with {describe_exit(self.children[label].returncode)}", "red")
        return 1 if self.failed or bad else 0


def _try_client(endpoint: str) -> zenoh.Session | None:
    """A client session if the router answers right now (a refused dial fails in milliseconds)."""
    try:
        return zenoh.open(zenoh_config(endpoint_settings(endpoint)))
    except zenoh.ZError:
        return None
