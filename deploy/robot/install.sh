#!/usr/bin/env bash
# Install and start riskfield on a robot computer: the robot's own Zenoh router (dialling the
# server's), the safety filter and the hardware bridges, as systemd services.
#
#   sudo deploy/robot/install.sh --server tcp/10.0.0.2:7447 [options]
#
#   --server ENDPOINT   the server site's router (required), e.g. tcp/10.0.0.2:7447 or tls/srv:7447
#   --robot ID          robot id, the key prefix part (default limo1)
#   --services "A B"    nodes to run (default "camera limo joystick safety-filter"; e.g. "safety-filter mavlink")
#   --listen ENDPOINT   where the robot's router serves its nodes (default tcp/127.0.0.1:7447); beyond
#                       loopback the router starts only with --secrets (TLS and users)
#   --secrets DIR       enable TLS + user/password: DIR is what `riskfield secrets --robot ID` made:
#                       certs/ (ID.router and ID.SERVICE), ID.*.env, users.txt, router-secure.json5
#   --limo-port DEV     LIMO serial port (default /dev/ttyTHS1)
#   --camera DEV        camera source (default /dev/video0; a video file or image folder works too)
#   --mavlink-url URL   the autopilot link (default udpin:127.0.0.1:14550: mavlink-router or a
#                       companion link on this computer; a serial port works too, e.g. /dev/ttyACM0)
#   --dry-run           bring-up: the LIMO bridge sends stop frames only and counts what it withheld
#   --prefix DIR        installation folder (default /opt/riskfield)
#   --root DIR          install below DIR instead of / (packaging, tests); implies --no-start
#   --no-pip            do not create the virtualenv (it exists, or the image provides it)
#   --no-start          install only; do not enable and start the units
#
# Only the robot site's extras are installed (deploy/requirements.py SITES: `robot` — numpy, scipy,
# numba, pyserial, pymavlink, evdev — and `camera`, PyAV): no torch, no open3d. Re-running updates
# the installation in place. Remove with:
#   systemctl disable --now riskfield-router 'riskfield@*'; rm -r /opt/riskfield /etc/riskfield \
#     /etc/systemd/system/riskfield-router.service /etc/systemd/system/riskfield@.service
set -euo pipefail

HERE="$(cd "$(dirname "$0")" && pwd)"
REPO="$(cd "$HERE/../.." && pwd)"
SERVER=""
ROBOT=limo1
SERVICES="camera limo joystick safety-filter"
LISTEN=tcp/127.0.0.1:7447
SECRETS=""
LIMO_PORT=/dev/ttyTHS1
CAMERA=/dev/video0
DRY_RUN=false
MAVLINK_URL=udpin:127.0.0.1:14550
PREFIX=/opt/riskfield
ROOT=""
PIP=1
START=1

die() { echo "install: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case $1 in
    --server) SERVER=${2:?}; shift 2 ;;
    --robot) ROBOT=${2:?}; shift 2 ;;
    --services) SERVICES=${2:?}; shift 2 ;;
    --listen) LISTEN=${2:?}; shift 2 ;;
    --secrets) SECRETS="$(cd "${2:?}" && pwd)"; shift 2 ;;
    --limo-port) LIMO_PORT=${2:?}; shift 2 ;;
    --camera) CAMERA=${2:?}; shift 2 ;;
    --mavlink-url) MAVLINK_URL=${2:?}; shift 2 ;;
    --dry-run) DRY_RUN=true; shift ;;
    --prefix) PREFIX=${2:?}; shift 2 ;;
    --root) ROOT="$(mkdir -p "${2:?}" && cd "$2" && pwd)"; START=0; shift 2 ;;
    --no-pip) PIP=0; shift ;;
    --no-start) START=0; shift ;;
    -h|--help) sed -n '2,28p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
done
[ -n "$SERVER" ] || die "--server ENDPOINT is required (the server site's Zenoh router)"
[[ $SERVER =~ ^(tcp|tls|quic|udp)/.+:[0-9]+$ ]] || die "--server $SERVER: expected e.g. tcp/10.0.0.2:7447"
[[ $ROBOT =~ ^[A-Za-z0-9_.~+=@:-]+$ ]] || die "--robot $ROBOT: letters, digits and -_.~+=@:"
for s in $SERVICES; do
  case $s in
    safety-filter|limo|joystick|camera|mavlink|relay) ;;
    *) die "--services: $s does not run on the robot computer (camera, limo, joystick, safety-filter, mavlink)" ;;
  esac
done
if [ -n "$SECRETS" ]; then
  [[ $SERVER == tls/* ]] || die "--secrets needs a tls/ server endpoint"
  [ -f "$SECRETS/$ROBOT.router.env" ] && [ -f "$SECRETS/router-secure.json5" ] \
    || die "--secrets $SECRETS has no $ROBOT.router.env or router-secure.json5: make them with riskfield secrets --robot $ROBOT"
  LISTEN=${LISTEN/#tcp\//tls/}
fi

SYS_ETC=/etc/riskfield  # paths written into files are those of the running system
ETC="$ROOT$SYS_ETC"
UNITS="$ROOT/etc/systemd/system"
DEST="$ROOT$PREFIX"
if [ "$(id -u)" -ne 0 ] && [ -z "$ROOT" ]; then
  die "run as root (sudo), or use --root DIR to stage an installation"
fi

# -- the software -------------------------------------------------------------------------
mkdir -p "$DEST" "$ETC" "$UNITS"
if [ "$PIP" = 1 ]; then
  python3 -c 'import sys; assert sys.version_info >= (3, 11), sys.version' \
    || die "Python 3.11 or newer is needed (python3 is $(python3 --version 2>&1))"
  [ -x "$DEST/venv/bin/python" ] || python3 -m venv "$DEST/venv"
  "$DEST/venv/bin/python" -m pip install -q --upgrade pip
  "$DEST/venv/bin/python" -m pip install -q "$REPO[$(python3 "$REPO/deploy/requirements.py" --extras robot-site)]"
  # Compile the filter's step once now (numba's cache), not on the robot's first start.
  "$DEST/venv/bin/python" -c "from riskfield.services.safety_filter.filter import SafetyFilter; SafetyFilter()"
fi

# -- settings -------------------------------------------------------------------------------
# Shared by the nodes: they dial the robot's router on this computer.
{
  echo "# riskfield nodes on this robot computer (deploy/robot/install.sh)."
  echo "RISKFIELD_MODE=client"
  echo "RISKFIELD_CONNECT=${LISTEN/0.0.0.0/127.0.0.1}"
  echo "RISKFIELD_ROBOT=$ROBOT"
  echo "RISKFIELD_CONNECT_TIMEOUT_S=60"
  echo "RISKFIELD_LIMO_PORT=$LIMO_PORT"
  echo "RISKFIELD_CAMERA_SOURCE=$CAMERA"
  echo "RISKFIELD_DRY_RUN=$DRY_RUN"
  echo "RISKFIELD_MAVLINK_URL=$MAVLINK_URL"
} >"$ETC/robot.env"
# The router: serves the nodes here and dials the server's router.
{
  echo "# The robot site's Zenoh router (deploy/robot/install.sh)."
  echo "RISKFIELD_MODE=router"
  echo "RISKFIELD_LISTEN=$LISTEN"
  echo "RISKFIELD_CONNECT=$SERVER"
  echo "RISKFIELD_ROBOT=$ROBOT"
} >"$ETC/router.env"

# A node's identity drop-in is this install's alone (a later install without --secrets has none).
rm -f "$UNITS"/riskfield@*.service.d/identity.conf
if [ -n "$SECRETS" ]; then
  # Readable by every node's user: the certificates are public; the keys are 0600 inside.
  install -d -m 755 "$ETC/tls"
  install -m 644 "$SECRETS/certs/ca.pem" "$ETC/tls/ca.pem"
  install -m 644 "$SECRETS/certs/$ROBOT.router.pem" "$ETC/tls/router.pem"
  install -m 600 "$SECRETS/certs/$ROBOT.router.key" "$ETC/tls/router.key"
  # This robot's router checks only this robot's nodes: the fleet's other passwords stay off it.
  [ -f "$SECRETS/$ROBOT.users.txt" ] || {
    echo "install: $SECRETS/$ROBOT.users.txt is missing: run riskfield secrets --robot $ROBOT (keeps the passwords)" >&2
    exit 2
  }
  install -m 600 "$SECRETS/$ROBOT.users.txt" "$ETC/users.txt"
  install -m 644 "$SECRETS/router-secure.json5" "$ETC/router.json5"
  {
    echo "RISKFIELD_ZENOH_CONFIG=$SYS_ETC/router.json5"
    cat "$SECRETS/$ROBOT.router.env"
  } >>"$ETC/router.env"
  for s in $SERVICES; do
    install -m 644 "$SECRETS/certs/$ROBOT.$s.pem" "$ETC/tls/$s.pem"
    install -m 600 "$SECRETS/certs/$ROBOT.$s.key" "$ETC/tls/$s.key"
    {
      echo "# $s's identity $ROBOT.$s: its certificate and its user (protocol/keys.py ROUTES say what it may do)."
      echo "RISKFIELD_TLS_ROOT_CA=$SYS_ETC/tls/ca.pem"
      echo "RISKFIELD_TLS_CERT=$SYS_ETC/tls/$s.pem"
      echo "RISKFIELD_TLS_MTLS=true"
      if [ "$s" = safety-filter ]; then  # a source is the key it puts on, cmd/ref/<source>: the ACL binds it
        echo "RISKFIELD_REF_PLAIN_KEY=false"
      fi
      cat "$SECRETS/$ROBOT.$s.env"
    } >"$ETC/$s.env"
    # The key stays root's; systemd hands this node alone a copy (riskfield@.service says why). Not in
    # $s.env: an EnvironmentFile= would override the unit's Environment=.
    install -d "$UNITS/riskfield@$s.service.d"
    {
      echo "# $s's TLS key, for this node only (deploy/robot/install.sh)."
      echo "[Service]"
      echo "LoadCredential=tls.key:$SYS_ETC/tls/$s.key"
      echo "Environment=RISKFIELD_TLS_KEY=%d/tls.key"
    } >"$UNITS/riskfield@$s.service.d/identity.conf"
  done
fi
# The filter keeps the risk configuration in force (set over the wire) with its version across restarts,
# in its unit's StateDirectory (/var/lib/riskfield/safety-filter, its user's alone). Only the filter has
# the setting: robot.env, which every node reads, must not name it.
case " $SERVICES " in
  *" safety-filter "*) echo "RISKFIELD_STATE_DIR=/var/lib/riskfield/safety-filter" >>"$ETC/safety-filter.env" ;;
esac
chmod 600 "$ETC"/*.env

# -- units ----------------------------------------------------------------------------------
for unit in riskfield-router.service riskfield@.service; do
  sed -e "s#@PREFIX@#$PREFIX#g" -e "s#@ETC@#$SYS_ETC#g" "$HERE/$unit" >"$UNITS/$unit"
done

echo "install: units in $UNITS, settings in $ETC (robot $ROBOT, server $SERVER, nodes: $SERVICES)"
if [ "$START" = 1 ]; then
  # The router's user; the nodes are users of their own (riskfield@.service: DynamicUser). Settings and
  # node keys stay root's (systemd reads them); the router reads its own key and users itself.
  id riskfield >/dev/null 2>&1 || useradd --system --home-dir "$PREFIX" --shell /usr/sbin/nologin riskfield
  for g in dialout input video; do getent group "$g" >/dev/null || groupadd --system "$g"; done
  if [ -n "$SECRETS" ]; then chown riskfield "$ETC/users.txt" "$ETC/tls/router.key"; fi
  systemctl daemon-reload
  units=(riskfield-router.service)
  for s in $SERVICES; do units+=("riskfield@$s.service"); done
  systemctl enable --now "${units[@]}"
  systemctl --no-pager --lines=0 status "${units[@]}" || true
fi
