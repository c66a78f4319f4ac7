#!/usr/bin/env bash
# Make Zenoh user/password credentials for a deployment.
#
#   deploy/make-users.sh [-o DIR] [USER ...]
#
# DIR (default deploy/secrets) receives users.txt, the server router's dictionary (`user:password`
# lines, transport/auth/usrpwd/dictionary_file), ROBOT.users.txt, a robot router's (its own
# identities' lines only), and USER.env per user with RISKFIELD_USER and
# RISKFIELD_PASSWORD for that node's environment (compose env_file, systemd EnvironmentFile).
# Existing users keep their password; new ones get 24 random URL-safe characters. Every file is
# mode 0600: Zenoh's usrpwd needs the passwords themselves (it checks an HMAC of the stored one, so
# it cannot take hashes), so only the user that runs the service may read them.
# The user names are a deployment's identities, ROBOT.ROLE, which the routers' generated access
# control knows (services/runtime/acl.py); `riskfield secrets --robot ID ...` calls this script
# with all of them. Each name must also be its node certificate's common name (deploy/make-certs.sh).
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
  echo "make-users: name the identities (ROBOT.ROLE), or run: riskfield secrets --robot ID ..." >&2
  exit 2
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

# A robot's router checks only that robot's identities (ROBOT.ROLE): ROBOT.users.txt holds just their
# lines, so the fleet's other passwords never reach a robot (compose.secure.yml, robot/install.sh).
for robot in $(printf '%s\n' "${USERS[@]}" | grep -F . | cut -d. -f1 | sort -u); do
  awk -F: -v p="$robot." 'index($1, p) == 1' "$OUT/users.txt" >"$OUT/$robot.users.txt"
  echo "make-users: $robot's router dictionary ($OUT/$robot.users.txt)"
done
