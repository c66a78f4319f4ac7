"""Fixtures for the deployment tests: the repository's deploy folder and a deployment's
secrets made by its own generator (`riskfield secrets`: services/runtime/acl.py) in a tmp dir."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from riskfield.services.runtime.acl import make_secrets

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"

#: The robots of the test deployment: every security test's identities are theirs.
ROBOTS = ("t_sec", "t_sec2")
#: A valid user with a valid certificate that the access control does not know: no role at all.
NOBODY = "nobody"


@dataclass(frozen=True)
class Secrets:
    root: Path  # plays /etc/riskfield: certs/, users.txt and router-secure.json5 (`riskfield secrets`)
    foreign: Path  # certificates from another CA (an attacker's, or another deployment's)
    passwords: dict[str, str]

    @property
    def tls(self) -> Path:
        return self.root / "certs"

    def cert(self, name: str) -> tuple[Path, Path]:
        return self.tls / f"{name}.pem", self.tls / f"{name}.key"

    def router_config(self, site: str, dest: Path) -> Path:
        """The generated router-secure.json5 with /etc/riskfield/ pointing at this tmp deployment
        and the site's router certificate installed as tls/router.{pem,key} — what compose and
        the robot installer do. ``site`` is ``server`` or a robot id (that robot's router)."""
        site_dir = dest / f"site-{site}"
        (site_dir / "tls").mkdir(parents=True, exist_ok=True)
        name = "router-server" if site == "server" else f"{site}.router"
        shutil.copy(self.tls / "ca.pem", site_dir / "tls" / "ca.pem")
        shutil.copy(self.tls / f"{name}.pem", site_dir / "tls" / "router.pem")
        shutil.copy(self.tls / f"{name}.key", site_dir / "tls" / "router.key")
        users = "users.txt" if site == "server" else f"{site}.users.txt"  # a robot's: its identities only
        shutil.copy(self.root / users, site_dir / "users.txt")
        text = (self.root / "router-secure.json5").read_text()
        cfg = site_dir / "router.json5"
        cfg.write_text(text.replace("/etc/riskfield/", f"{site_dir}/"))
        return cfg


def _run(cmd: list[str]) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)


@pytest.fixture(scope="session")
def secrets(tmp_path_factory: pytest.TempPathFactory) -> Secrets:
    """The test deployment's secrets, made by `riskfield secrets` for ROBOTS (and NOBODY by the
    scripts it calls), in a tmp dir."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    root = tmp_path_factory.mktemp("etc-riskfield")
    make_secrets(root, ROBOTS)
    _run(["bash", str(DEPLOY / "make-certs.sh"), "-o", str(root / "certs"), NOBODY])
    _run(["bash", str(DEPLOY / "make-users.sh"), "-o", str(root), NOBODY])
    foreign = tmp_path_factory.mktemp("foreign-ca")
    _run(["bash", str(DEPLOY / "make-certs.sh"), "-o", str(foreign), f"{ROBOTS[0]}.safety-filter",
          f"{ROBOTS[0]}.router"])
    passwords = dict(line.split(":", 1) for line in (root / "users.txt").read_text().split())
    return Secrets(root=root, foreign=foreign, passwords=passwords)
