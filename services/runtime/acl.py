"""The secure routers' access control, generated from who produces and consumes each key
(``protocol.keys.ROUTES``, ``ROLES``): ``riskfield acl`` writes it, ``riskfield secrets`` makes the
identities it names, and a test checks that the shipped ``deploy/zenoh/router-secure.json5`` is
this module's output.

Zenoh's format (eclipse-zenoh/zenoh, DEFAULT_CONFIG.json5, ``access_control``): ``rules`` (id,
permission, flows, messages, key_exprs), ``subjects`` (usernames, cert_common_names: a subject
with both matches only a session whose user AND certificate name are in them) and ``policies``
(rules granted to subjects). Default deny. How Zenoh decides
(zenoh/src/net/routing/interceptor/authorization.rs, ``PolicyEnforcer::policy_decision_point``): a
deny rule including the message's key expression refuses it, else an allow rule must include it
(``nodes_including``), so a put on ``rf/limo1/**`` or ``**`` is included in no rule here and is
refused; a session matching several subjects is allowed when any of them allows
(interceptor/access_control.rs, ``action``). So there is no catch-all subject: every identity is
granted exactly what the declaration gives its role, on its own robot's keys only.

Identities are per robot, ``{robot}.{role}`` (user name and certificate common name alike), and
``{robot}.router`` for the robot's router. The server's router is known by its certificate alone
(``router-server``): seen from a robot's router, which dialled it, the link has no user name
(usrpwd authenticates the dialler only). Between the routers only the data one site produces and
the other consumes is let through, in each direction.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from riskfield.protocol.keys import READ_ALL, ROLES, ROS_ROUTES, ROUTES, Keys

SERVER_ROUTER = "router-server"
PUT = ["put", "delete"]
#: Declarations a session is told about (who subscribes, serves, is alive): its publishers match
#: on them and send only what has a subscriber. They carry no data, so every session is told all
#: of them: a put it may not make then reaches its router, which refuses it, rather than never
#: leaving (which a test could not tell from a refusal).
DECLARATIONS = ["declare_subscriber", "declare_queryable", "liveliness_token"]
DISCOVER = ["liveliness_query", "declare_liveliness_subscriber"]


def identity(robot: str, role: str) -> str:
    """The user name and certificate common name of ``role`` for ``robot``."""
    if role != "router" and role not in ROLES:
        raise ValueError(f"unknown role {role!r}; known: router, {', '.join(ROLES)}")
    return f"{Keys(robot=robot).robot}.{role}"


def identities(robots: Iterable[str]) -> list[str]:
    """Every identity of a deployment: per robot its router and every role."""
    return [identity(r, role) for r in robots for role in ("router", *ROLES)]


def _queryable(relative: str) -> bool:
    return relative.endswith("/query")


@dataclass(frozen=True)
class _Grants:
    put: list[str]
    alive: list[str]
    serve: list[str]
    read: list[str]
    ask: list[str]


def _grants(keys: Keys, role: str) -> _Grants:
    spec = ROLES[role]
    put = [keys.key(k) for k, r in ROUTES.items() if role in r.producers and not _queryable(k)]
    serve = [keys.key(k) for k, r in ROUTES.items() if role in r.producers and _queryable(k)]
    ask = [keys.key(k) for k, r in ROUTES.items() if role in r.consumers and _queryable(k)]
    read = [keys.key(k) for k, r in ROUTES.items() if role in r.consumers and not _queryable(k)]
    put += [f"{keys.robot}/{t}" for t, r in ROS_ROUTES.items() if role in r.producers]
    read += [f"{keys.robot}/{t}" for t, r in ROS_ROUTES.items() if role in r.consumers]
    alive = []
    if spec.service is not None:
        put.append(keys.status(spec.service))
        read.append(keys.status(spec.service))  # its container's healthcheck hears its status
        alive.append(keys.alive(spec.service))
    if role == "zenoh-bridge-ros2dds":  # its discovery tokens (zenoh-plugin-ros2dds src/liveliness_mgt.rs)
        alive.append("@/*/@ros2_lv/**")
    if role in READ_ALL:
        read = [f"{keys.root}/**"]
        ask = [keys.key(k) for k in ROUTES if _queryable(k)]
    return _Grants(put, alive, serve, read, ask)


def _site_keys(keys: Keys, source: str) -> tuple[list[str], list[str]]:
    """What roles at ``source`` produce that roles at the other site consume: (data, queryables)."""
    def at(role: str, site: str) -> bool:
        return ROLES[role].site == site
    other = "server" if source == "robot" else "robot"
    data, queries = [], []
    for k, r in ROUTES.items():
        made_here = any(at(p, source) for p in r.producers)
        needed = any(at(c, other) for c in (*r.consumers, *READ_ALL))
        if made_here and needed:
            (queries if _queryable(k) else data).append(keys.key(k))
    for t, r in ROS_ROUTES.items():
        if any(at(p, source) for p in r.producers) and any(at(c, other) for c in r.consumers):
            data.append(f"{keys.robot}/{t}")
    if any(at(c, other) for c in READ_ALL):  # statuses reach the operators' tools
        data += [keys.status(s.service) for s in ROLES.values() if s.service is not None and s.site == source]
    return data, queries


def _rule(rid: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict | None:
    if not key_exprs:
        return None
    return {"id": rid, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": key_exprs}


def _link_rules(rid: str, taken: tuple[list[str], list[str]], given: tuple[list[str], list[str]],
                declare: list[str], own: list[str]) -> list[dict | None]:
    """The rules of one link between the sites, for the subject ``rid``: ``taken`` (keys put, keys
    queried) flows in, ``given`` flows out, and queries on either are answered the other way. The
    robot's router and the server's router (per robot) are this with the two swapped."""
    (puts_in, queries_in), (puts_out, queries_out) = taken, given
    return [
        _rule(f"{rid}/in", "ingress", PUT, puts_in),
        _rule(f"{rid}/out", "egress", PUT, puts_out),
        _rule(f"{rid}/serve-in", "ingress", ["declare_queryable", "reply"], queries_in),
        _rule(f"{rid}/ask-in", "ingress", ["query"], queries_out),
        _rule(f"{rid}/ask-out", "egress", ["query"], queries_in),
        _rule(f"{rid}/answer-out", "egress", ["reply"], queries_out),
        _rule(f"{rid}/declare-in", "ingress", declare, own),
        _rule(f"{rid}/declare-out", "egress", declare, own),
    ]


def access_control(robots: Sequence[str], prefix: str = "rf") -> dict:
    """Zenoh's ``access_control`` section for ``robots`` under ``prefix``."""
    if not robots:
        raise ValueError("access control for no robot: name at least one")
    rules: list[dict] = []
    subjects: list[dict] = []
    policies: list[dict] = []
    server_rules: list[str] = []

    def add(*candidates: dict | None) -> list[str]:
        out = [r for r in candidates if r is not None]
        rules.extend(out)
        return [r["id"] for r in out]

    for robot in robots:
        keys = Keys(robot=robot, prefix=prefix)
        own = [f"{keys.root}/**", f"{robot}/**"]
        for role in ROLES:
            who = identity(robot, role)
            g = _grants(keys, role)
            ids = add(
                _rule(f"{who}/put", "ingress", PUT, g.put),
                _rule(f"{who}/alive", "ingress", ["liveliness_token"], g.alive),
                _rule(f"{who}/serve", "ingress", ["declare_queryable", "reply"], g.serve),
                _rule(f"{who}/served", "egress", ["query"], g.serve),
                _rule(f"{who}/subscribe", "ingress", ["declare_subscriber"], g.read),
                _rule(f"{who}/receive", "egress", PUT, g.read),
                _rule(f"{who}/ask", "ingress", ["query"], g.ask),
                _rule(f"{who}/answered", "egress", ["reply"], g.ask),
            )
            subjects.append({"id": who, "usernames": [who], "cert_common_names": [who]})
            policies.append({"id": who, "subjects": [who], "rules": ids})
        # Between the sites: at the server's router the robot's router is this robot's identity; at
        # the robot's router the server's is SERVER_ROUTER. Each lets in what the far site makes and
        # this one needs, and sends what the far site needs; declarations pass on the robot's keys.
        up, up_queries = _site_keys(keys, "robot")
        down, down_queries = _site_keys(keys, "server")
        router = identity(robot, "router")
        declare = [*DECLARATIONS, *DISCOVER]
        robot_router_rules = add(*_link_rules(router, (up, up_queries), (down, down_queries), declare, own))
        subjects.append({"id": router, "usernames": [router], "cert_common_names": [router]})
        policies.append({"id": router, "subjects": [router], "rules": robot_router_rules})
        server_rules += add(*_link_rules(f"{SERVER_ROUTER}/{robot}", (down, down_queries), (up, up_queries),
                                         declare, own))
    # Declarations and presence only, no data: any authenticated session is told who subscribes,
    # serves and is alive (DECLARATIONS), and may ask which robot services are alive. A session
    # without a role is answered that, in order after its refused messages, so that a refusal can
    # be observed as done.
    alive = [Keys(robot=r, prefix=prefix).key("alive/*") for r in robots]
    everyone = add(_rule("everyone/discover", "ingress", DISCOVER, alive),
                   _rule("everyone/told", "egress", DECLARATIONS, ["**"]))
    subjects.append({"id": "everyone"})
    policies.append({"id": "everyone", "subjects": ["everyone"], "rules": everyone})
    subjects.append({"id": SERVER_ROUTER, "cert_common_names": [SERVER_ROUTER]})
    policies.append({"id": SERVER_ROUTER, "subjects": [SERVER_ROUTER], "rules": server_rules})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


_HEADER = """\
// GENERATED by `riskfield acl{args}` from protocol/keys.py (ROUTES, ROLES): do not edit by hand;
// change the declaration and run it again (a test checks this file is its output).
//
// Zenoh router of a riskfield site across an untrusted network: TLS with mutual
// authentication on every link, user/password on every session, and access control.
//
// One file serves both sites. The server site's router listens; the robot site's router
// also dials the server's (`--connect tls/SERVER:7447`). Its own credentials (needed to dial
// another router) come from the environment, never from this file: `riskfield run router`
// reads RISKFIELD_USER/RISKFIELD_PASSWORD (identity ROBOT.router).
//
// Files (`riskfield secrets` makes them; compose and the robot installer place them here):
//   /etc/riskfield/tls/ca.pem                 the deployment's CA
//   /etc/riskfield/tls/router.pem, router.key this router's certificate (CN router-server, or ROBOT.router)
//   /etc/riskfield/users.txt                  user:password lines, mode 0600: Zenoh's usrpwd
//                                             authenticator needs each password itself (it checks an
//                                             HMAC of it under a nonce), so it cannot hold hashes
//
// Who may do what (services/runtime/acl.py): one identity per robot and role, ROBOT.ROLE, both
// as user name and as certificate common name. Each puts only its robot's keys its role produces
// and receives only the keys it consumes; routers forward only what the other site consumes.
// Robots: {robots}; prefix: {prefix}.
"""

_BODY = """\
{{
  mode: "router",
  listen: {{ endpoints: ["tls/[::]:7447"] }},
  scouting: {{
    multicast: {{ enabled: false }},
    gossip: {{ enabled: true }},
  }},
  transport: {{
    shared_memory: {{ enabled: false }},  // as router.json5
    unicast: {{ compression: {{ enabled: true }} }},  // as router.json5: LZ4 between the two sites' routers
    link: {{
      tls: {{
        root_ca_certificate: "/etc/riskfield/tls/ca.pem",
        listen_certificate: "/etc/riskfield/tls/router.pem",
        listen_private_key: "/etc/riskfield/tls/router.key",
        // The same certificate identifies this router when it dials the other site.
        connect_certificate: "/etc/riskfield/tls/router.pem",
        connect_private_key: "/etc/riskfield/tls/router.key",
        // Mutual TLS: a peer without a certificate signed by the CA is refused at the link.
        enable_mtls: true,
        verify_name_on_connect: true,
      }},
    }},
    auth: {{
      usrpwd: {{
        dictionary_file: "/etc/riskfield/users.txt",
      }},
    }},
  }},
  // As router.json5: a robot's router dials the server's again within 1 s of the link's return,
  // and the filter's status leaves at 10 Hz (its consumers are people).
  connect: {{
    retry: {{ period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 }},
  }},
  downsampling: [
    {{ id: "link-egress", flows: ["egress"], messages: ["put"],
      rules: [{{ key_expr: "**/safety/status", freq: 10.0 }}] }},
  ],
  // No REST plugin here: its HTTP API would publish past the access control below.
  access_control: {acl},
}}
"""


def _json(value: object, indent: int) -> str:
    """One rule, subject or policy per line: readable, and still JSON (which JSON5 reads)."""
    pad = " " * indent
    if isinstance(value, dict) and any(isinstance(v, list) and v and isinstance(v[0], dict)
                                       for v in value.values()):
        items = [f'{pad}  {json.dumps(k)}: {_json(v, indent + 2).lstrip()},' for k, v in value.items()]
        return "{\n" + "\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list) and value and isinstance(value[0], dict):
        return "[\n" + "\n".join(f"{pad}  {json.dumps(v)}," for v in value) + f"\n{pad}]"
    return json.dumps(value)


def router_config(robots: Sequence[str], prefix: str = "rf") -> str:
    """The whole secure router config (JSON5) for ``robots``: what ``riskfield acl`` writes."""
    args = "".join(f" --robot {r}" for r in robots) + ("" if prefix == "rf" else f" --prefix {prefix}")
    header = _HEADER.format(args=args, robots=", ".join(robots), prefix=prefix)
    return header + _BODY.format(acl=_json(access_control(robots, prefix), 2))


def deploy_dir() -> Path:
    """The checkout's ``deploy/`` folder, whose scripts make certificates and passwords."""
    here = Path(__file__).resolve().parents[2] / "deploy"
    if not (here / "make-users.sh").is_file():
        raise FileNotFoundError(f"{here}/make-users.sh not found: `riskfield secrets` runs from a riskfield "
                                "checkout (git clone), where deploy/ holds the scripts it calls")
    return here


def make_secrets(out: Path, robots: Sequence[str], prefix: str = "rf", certs: bool = True) -> list[Path]:
    """Per-robot credentials in ``out``: ``users.txt`` (the server router's dictionary),
    ``ROBOT.users.txt`` (a robot router's: that robot's identities only), one
    ``IDENTITY.env`` per identity (deploy/make-users.sh; both mode 0600, for the one service user
    that reads each), certificates in ``out/certs`` (deploy/make-certs.sh; keys 0600), and the
    routers' ``router-secure.json5`` for these robots. Existing passwords and the CA are kept."""
    scripts = deploy_dir()
    names = identities(robots)
    out.mkdir(parents=True, exist_ok=True)
    subprocess.run(["bash", str(scripts / "make-users.sh"), "-o", str(out), *names], check=True,
                   capture_output=True, text=True, timeout=120)
    made = [out / "users.txt", *(out / f"{r}.users.txt" for r in robots), *(out / f"{n}.env" for n in names)]
    for path in made:  # whatever umask the caller had: readable by the owner only
        path.chmod(0o600)
    if certs:
        if shutil.which("openssl") is None:
            raise FileNotFoundError("openssl is needed for the certificates (or pass --no-certs)")
        subprocess.run(["bash", str(scripts / "make-certs.sh"), "-o", str(out / "certs"), SERVER_ROUTER, *names],
                       check=True, capture_output=True, text=True, timeout=600)
        made.append(out / "certs")
    acl = out / "router-secure.json5"
    acl.write_text(router_config(robots, prefix))
    made.append(acl)
    return made
