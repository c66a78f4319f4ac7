#!/usr/bin/env bash
# Make Zenoh user/password credentials for a deployment.
#
#   deploy/make-users.sh [-o DIR] [USER ...]
#
# DIR (default deploy/secrets) receives users.txt, the routers' dictionary (`user:password`
# lines, transport/auth/usrpwd/dictionary_file), and USER.env per user with RISKFIELD_USER and
# RISKFIELD_PASSWORD for that node's environment (compose env_file, systemd EnvironmentFile).
# Existing users keep their password; new ones get 24 random URL-safe characters.
# The user name is the role the routers' access control knows (deploy/zenoh/router-secure.json5),
# and it must also be the common name of the node's certificate (deploy/make-certs.sh NAME):
# a role needs both. Each role may put only its own exact keys (safety-filter: cmd/safe;
# joystick, teleop, navigator, ros2-bridge: cmd/ref; operator: cmd/ref, nav/goal, the risk
# config; the other services their data); any other user only subscribes and queries.
set -euo pipefail

OUT=""
while getopts "o:h" opt; do
  case $opt in
    o) OUT=$OPTARG ;;
    h) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) exit 2 ;;
  esac
done
shift $((OPTIND - 1))
[ -n "$OUT" ] || OUT="$(cd "$(dirname "$0")" && pwd)/secrets"
USERS=("$@")
if [ ${#USERS[@]} -eq 0 ]; then
  USERS=(router safety-filter mapping perception navigator simulator limo joystick mavlink operator teleop
         ros2-bridge zenoh-bridge-ros2dds)
fi

mkdir -p "$OUT"
umask 077
touch "$OUT/users.txt"
for user in "${USERS[@]}"; do
  if ! [[ $user =~ ^[A-Za-z0-9][A-Za-z0-9._-]*$ ]]; then
    echo "make-users: bad user name '$user'" >&2
    exit 2
  fi
  if ! grep -q "^$user:" "$OUT/users.txt"; then
    password=$(head -c 18 /dev/urandom | base64 | tr '+/' '-_')
    echo "$user:$password" >>"$OUT/users.txt"
  fi
  password=$(grep "^$user:" "$OUT/users.txt" | head -1 | cut -d: -f2-)
  printf 'RISKFIELD_USER=%s\nRISKFIELD_PASSWORD=%s\n' "$user" "$password" >"$OUT/$user.env"
  echo "make-users: $user ($OUT/$user.env)"
done
