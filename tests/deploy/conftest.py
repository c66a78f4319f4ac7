"""Fixtures for the deployment tests: the repository's deploy folder and a deployment's
secrets made by its own scripts (deploy/make-certs.sh, deploy/make-users.sh) in a tmp dir."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"

#: Certificates every security test needs (CN = name).
CERT_NAMES = ("router-server", "router-robot", "safety-filter", "teleop", "limo", "mapping", "planner")
#: Users in the routers' dictionary; "planner" has no role (subscribe and query only).
USER_NAMES = ("router", "safety-filter", "teleop", "limo", "mapping", "operator", "planner", "relay")


@dataclass(frozen=True)
class Secrets:
    root: Path  # plays /etc/riskfield: tls/ and users.txt
    foreign: Path  # certificates from another CA (an attacker's, or another deployment's)
    passwords: dict[str, str]

    @property
    def tls(self) -> Path:
        return self.root / "tls"

    def cert(self, name: str) -> tuple[Path, Path]:
        return self.tls / f"{name}.pem", self.tls / f"{name}.key"

    def router_config(self, site: str, dest: Path) -> Path:
        """deploy/zenoh/router-secure.json5 with /etc/riskfield/ pointing at this tmp deployment
        and the site's router certificate installed as tls/router.{pem,key} — what compose and
        the robot installer do. Nothing else of the shipped file changes."""
        site_dir = dest / f"site-{site}"
        (site_dir / "tls").mkdir(parents=True, exist_ok=True)
        shutil.copy(self.tls / "ca.pem", site_dir / "tls" / "ca.pem")
        shutil.copy(self.tls / f"router-{site}.pem", site_dir / "tls" / "router.pem")
        shutil.copy(self.tls / f"router-{site}.key", site_dir / "tls" / "router.key")
        shutil.copy(self.root / "users.txt", site_dir / "users.txt")
        text = (DEPLOY / "zenoh" / "router-secure.json5").read_text()
        cfg = site_dir / "router.json5"
        cfg.write_text(text.replace("/etc/riskfield/", f"{site_dir}/"))
        return cfg


def _run(cmd: list[str]) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=60)


@pytest.fixture(scope="session")
def secrets(tmp_path_factory: pytest.TempPathFactory) -> Secrets:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    root = tmp_path_factory.mktemp("etc-riskfield")
    _run(["bash", str(DEPLOY / "make-certs.sh"), "-o", str(root / "tls"), *CERT_NAMES])
    _run(["bash", str(DEPLOY / "make-users.sh"), "-o", str(root), *USER_NAMES])
    foreign = tmp_path_factory.mktemp("foreign-ca")
    _run(["bash", str(DEPLOY / "make-certs.sh"), "-o", str(foreign), "safety-filter", "router-robot"])
    passwords = dict(line.split(":", 1) for line in (root / "users.txt").read_text().split())
    return Secrets(root=root, foreign=foreign, passwords=passwords)
