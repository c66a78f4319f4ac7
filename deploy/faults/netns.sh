#!/usr/bin/env bash
# Two network namespaces, a robot and a server, joined by one veth pair, and the faults a
# field network has: a cut link, delay, packet loss. Needs root and iproute2.
#
#   deploy/faults/netns.sh up            make the namespaces (robot 10.200.0.1, server 10.200.0.2)
#   deploy/faults/netns.sh cut | heal    take the link down / up again
#   deploy/faults/netns.sh delay MS [JITTER_MS]   add one-way delay on both ends (netem)
#   deploy/faults/netns.sh loss PCT      drop PCT % of packets in each direction
#   deploy/faults/netns.sh clear         remove delay and loss
#   deploy/faults/netns.sh exec robot|server CMD...   run CMD inside a namespace
#   deploy/faults/netns.sh status        addresses, link state, impairments
#   deploy/faults/netns.sh down          delete everything made by `up`
#   deploy/faults/netns.sh probe         exit 0 when this machine can make namespaces, 3 if not
#
# RF_NETNS (default "rf") names the pair: namespaces $RF_NETNS-robot and $RF_NETNS-server, links
# $RF_NETNS-r0 / $RF_NETNS-s0, so several labs can coexist. Delay and loss use the netem qdisc;
# where the kernel has no netem, loss falls back to a classic-BPF random match on the link's
# egress that redirects the chosen packets into a link that is down (the kernel drops them),
# and delay is refused (exit 4) so a caller can skip cleanly.
set -euo pipefail

NAME=${RF_NETNS:-rf}
ROBOT_NS=$NAME-robot
SERVER_NS=$NAME-server
ROBOT_IF=$NAME-r0
SERVER_IF=$NAME-s0
HOLE_IF=$NAME-h0  # a veth end kept down: packets redirected into it are dropped
ROBOT_IP=${RF_ROBOT_IP:-10.200.0.1}
SERVER_IP=${RF_SERVER_IP:-10.200.0.2}
[ ${#ROBOT_IF} -le 15 ] || { echo "netns: RF_NETNS=$NAME is too long for interface names" >&2; exit 2; }

ns_of() {
  case $1 in
    robot) echo "$ROBOT_NS" ;;
    server) echo "$SERVER_NS" ;;
    *) echo "netns: side must be robot or server, not '$1'" >&2; exit 2 ;;
  esac
}

has_netem() {
  # Probe on the robot's loopback: adding and removing a netem qdisc there touches nothing else.
  if ip netns exec "$ROBOT_NS" tc qdisc add dev lo root handle 1: netem delay 0ms 2>/dev/null; then
    ip netns exec "$ROBOT_NS" tc qdisc del dev lo root 2>/dev/null || true
    return 0
  fi
  return 1
}

clear_side() {
  local ns=$1 dev=$2
  ip netns exec "$ns" tc qdisc del dev "$dev" root 2>/dev/null || true
  ip netns exec "$ns" tc qdisc del dev "$dev" clsact 2>/dev/null || true
}

bpf_loss() {
  # Classic BPF: A = random u32; match (return -1) when A < threshold, else no match (0).
  local ns=$1 dev=$2 pct=$3 threshold
  threshold=$(awk -v p="$pct" 'BEGIN { printf "%d", p / 100 * 4294967295 }')
  ip -n "$ns" link show "$HOLE_IF" >/dev/null 2>&1 \
    || ip -n "$ns" link add "$HOLE_IF" type veth peer name "$NAME-h1"
  ip netns exec "$ns" tc qdisc add dev "$dev" clsact
  ip netns exec "$ns" tc filter add dev "$dev" egress bpf \
    bytecode "4,32 0 0 4294963256,53 0 1 $threshold,6 0 0 0,6 0 0 4294967295" \
    action mirred egress redirect dev "$HOLE_IF"
}

cmd=${1:-status}
shift || true
case $cmd in
  probe)
    probe=$NAME-probe$$
    if ip netns add "$probe" 2>/dev/null; then
      ip netns del "$probe"
      exit 0
    fi
    echo "netns: cannot create network namespaces here (needs root and iproute2)" >&2
    exit 3
    ;;
  up)
    ip netns add "$ROBOT_NS"
    ip netns add "$SERVER_NS"
    ip link add "$ROBOT_IF" type veth peer name "$SERVER_IF"
    ip link set "$ROBOT_IF" netns "$ROBOT_NS"
    ip link set "$SERVER_IF" netns "$SERVER_NS"
    ip -n "$ROBOT_NS" addr add "$ROBOT_IP/24" dev "$ROBOT_IF"
    ip -n "$SERVER_NS" addr add "$SERVER_IP/24" dev "$SERVER_IF"
    for ns in "$ROBOT_NS" "$SERVER_NS"; do ip -n "$ns" link set lo up; done
    ip -n "$ROBOT_NS" link set "$ROBOT_IF" up
    ip -n "$SERVER_NS" link set "$SERVER_IF" up
    echo "netns: $ROBOT_NS ($ROBOT_IP) <-> $SERVER_NS ($SERVER_IP)"
    ;;
  down)
    ip netns del "$ROBOT_NS" 2>/dev/null || true
    ip netns del "$SERVER_NS" 2>/dev/null || true
    ;;
  cut)
    ip -n "$ROBOT_NS" link set "$ROBOT_IF" down
    ip -n "$SERVER_NS" link set "$SERVER_IF" down
    ;;
  heal)
    ip -n "$ROBOT_NS" link set "$ROBOT_IF" up
    ip -n "$SERVER_NS" link set "$SERVER_IF" up
    ;;
  delay)
    ms=${1:?delay MS [JITTER_MS]}
    jitter=${2:-0}
    if ! has_netem; then
      echo "netns: this kernel has no netem qdisc: delay is unavailable (loss still works)" >&2
      exit 4
    fi
    for side in "$ROBOT_NS $ROBOT_IF" "$SERVER_NS $SERVER_IF"; do
      set -- $side
      clear_side "$1" "$2"
      ip netns exec "$1" tc qdisc add dev "$2" root netem delay "${ms}ms" "${jitter}ms"
    done
    ;;
  loss)
    pct=${1:?loss PCT}
    for side in "$ROBOT_NS $ROBOT_IF" "$SERVER_NS $SERVER_IF"; do
      set -- $side
      clear_side "$1" "$2"
      if has_netem; then
        ip netns exec "$1" tc qdisc add dev "$2" root netem loss "${pct}%"
      else
        bpf_loss "$1" "$2" "$pct"
      fi
    done
    ;;
  clear)
    clear_side "$ROBOT_NS" "$ROBOT_IF"
    clear_side "$SERVER_NS" "$SERVER_IF"
    ;;
  exec)
    ns=$(ns_of "${1:?exec robot|server CMD...}")
    shift
    exec ip netns exec "$ns" "$@"
    ;;
  status)
    for ns in "$ROBOT_NS" "$SERVER_NS"; do
      echo "== $ns"
      ip -n "$ns" -brief addr 2>/dev/null || echo "(absent)"
      ip netns exec "$ns" tc qdisc show 2>/dev/null | grep -v -E "noqueue|pfifo_fast" || true
      ip netns exec "$ns" tc filter show dev "$([ "$ns" = "$ROBOT_NS" ] && echo "$ROBOT_IF" || echo "$SERVER_IF")" \
        egress 2>/dev/null | grep -E "bpf|mirred" || true
    done
    ;;
  *)
    sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
