"""Container healthcheck of a riskfield image (docker-compose.yml ``healthcheck``).

Healthy once the container's node has published its status: a session with the node's own
settings (its RISKFIELD_* environment, so its own identity under the secure overlay) hears
``{prefix}/{robot}/status/{service}`` within a few status periods. The service is read from the
container's main process (``riskfield run SERVICE ...``), so one healthcheck serves every node.
The router's check is that it listens on its port: a session to it would need an identity of
its own under the access control, and every node's check goes through it anyway.

Exit 0 healthy, 1 not (docker's convention), with one line saying why.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path


def _main_command() -> list[str]:
    return [a.decode() for a in Path("/proc/1/cmdline").read_bytes().split(b"\0") if a]


def _option(args: list[str], name: str) -> str | None:
    for i, a in enumerate(args):
        if a == name and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(name + "="):
            return a.split("=", 1)[1]
    return None


def _listening(port: int) -> bool:
    """A socket in LISTEN (state 0A) on ``port``, from the kernel's tables of this network namespace."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if fields[3] == "0A" and int(fields[1].rsplit(":", 1)[1], 16) == port:
                return True
    return False


def main() -> int:
    args = _main_command()
    if "run" not in args or args.index("run") + 1 >= len(args):
        print(f"healthcheck: the main process is not `riskfield run SERVICE`: {args}")
        return 1
    service = args[args.index("run") + 1]
    if service == "router":
        listen = _option(args, "--listen") or "tcp/[::]:7447"
        port = int(listen.rsplit(":", 1)[1].split("#")[0].split("?")[0])
        ok = _listening(port)
        print(f"healthcheck: router {'listens' if ok else 'does not listen'} on {port}")
        return 0 if ok else 1

    import os

    from riskfield.protocol import Keys
    from riskfield.services.runtime.session import open_session
    from riskfield.services.runtime.settings import ENV_PREFIX, NodeSettings, env_names

    # Only the session's settings (connection, identity) matter here. The service's own variables
    # (the operator's RISKFIELD_TARGETS, ...) would be unknown keys to NodeSettings, which is strict:
    # they are the node's business, not this check's, and importing the service to know them would
    # cost every check seconds of CPU (numba, open3d).
    own = env_names(NodeSettings)
    for var in [v for v in os.environ if v.upper().startswith(ENV_PREFIX)]:
        if var.upper().partition("__")[0] not in own:
            del os.environ[var]

    overrides: dict[str, object] = {}
    connect = _option(args, "--connect")
    if connect:
        overrides["connect"] = [connect]
    settings = NodeSettings(**overrides).model_copy(update={"connect_timeout_s": 5.0, "listen": []})
    key = Keys(robot=settings.robot, prefix=settings.prefix).status(service)
    heard = threading.Event()
    with open_session(settings) as session:
        sub = session.declare_subscriber(key, lambda _sample: heard.set())
        ok = heard.wait(3.0 * settings.status_period_s + 1.0)
        sub.undeclare()
    print(f"healthcheck: {key} {'heard' if ok else 'not heard'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
