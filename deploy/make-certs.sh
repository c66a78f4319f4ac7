#!/usr/bin/env bash
# Make a certificate authority and one certificate per Zenoh participant of a deployment.
#
#   deploy/make-certs.sh [-o DIR] [-d DAYS] [NAME[=SAN,SAN...] ...]
#
# DIR (default deploy/secrets/certs) receives ca.pem + ca.key (kept if they already exist,
# so re-running adds participants without invalidating the others) and NAME.pem + NAME.key
# per participant. The certificate's common name is NAME, and NAME must be the participant's
# user name (deploy/make-users.sh): the routers' access control grants an identity only when the
# session's user AND its certificate's common name are both that identity, ROBOT.ROLE
# (services/runtime/acl.py, subjects), so one node's certificate with another node's password
# gets no rights. The server's router is router-server; a robot's router is ROBOT.router.
# `riskfield secrets --robot ID ...` calls this script with every identity of a deployment.
# SANs are DNS:host or IP:addr; without any,
# the certificate holds DNS:NAME, DNS:localhost and IP:127.0.0.1, which is what a container
# or a loopback test dials. Every leaf certificate is usable both as a TLS server (a router
# listening) and as a TLS client (a node or a router dialling, mutual TLS).
#
# Keys are ECDSA P-256 in PKCS#8 PEM (what rustls, inside Zenoh, reads). Needs openssl.
set -euo pipefail

OUT=""
DAYS=825
usage() { sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'; exit "${1:-0}"; }
while getopts "o:d:h" opt; do
  case $opt in
    o) OUT=$OPTARG ;;
    d) DAYS=$OPTARG ;;
    h) usage 0 ;;
    *) usage 2 ;;
  esac
done
shift $((OPTIND - 1))
[ -n "$OUT" ] || OUT="$(cd "$(dirname "$0")" && pwd)/secrets/certs"
command -v openssl >/dev/null || { echo "make-certs: openssl is required" >&2; exit 1; }

NAMES=("$@")
if [ ${#NAMES[@]} -eq 0 ]; then
  echo "make-certs: name the participants (router-server, ROBOT.ROLE), or run: riskfield secrets --robot ID ..." >&2
  exit 2
fi

mkdir -p "$OUT"
umask 077  # private keys readable by the owner only

if [ ! -f "$OUT/ca.pem" ] || [ ! -f "$OUT/ca.key" ]; then
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/ca.key" 2>/dev/null
  openssl req -x509 -new -key "$OUT/ca.key" -sha256 -days "$DAYS" -subj "/CN=riskfield-ca" \
    -addext "basicConstraints=critical,CA:TRUE,pathlen:0" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$OUT/ca.pem"
  echo "make-certs: new CA $OUT/ca.pem"
fi

for spec in "${NAMES[@]}"; do
  name=${spec%%=*}
  if ! [[ $name =~ ^[A-Za-z0-9][A-Za-z0-9._-]*$ ]]; then
    echo "make-certs: bad name '$name' (letters, digits, . _ -)" >&2
    exit 2
  fi
  sans="DNS:$name,DNS:localhost,IP:127.0.0.1"
  if [ "$spec" != "$name" ]; then
    sans=${spec#*=}
  fi
  ext=$(mktemp)
  trap 'rm -f "$ext"' EXIT
  cat >"$ext" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$sans
EOF
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$OUT/$name.key" 2>/dev/null
  openssl req -new -key "$OUT/$name.key" -subj "/CN=$name" -out "$OUT/$name.csr"
  openssl x509 -req -in "$OUT/$name.csr" -CA "$OUT/ca.pem" -CAkey "$OUT/ca.key" -CAcreateserial \
    -days "$DAYS" -sha256 -extfile "$ext" -out "$OUT/$name.pem" 2>/dev/null
  rm -f "$OUT/$name.csr" "$ext"
  echo "make-certs: $OUT/$name.pem ($sans)"
done
chmod 644 "$OUT"/*.pem
