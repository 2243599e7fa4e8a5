#!/usr/bin/env bash
# Three "machines" on one host, for trying the multi-host setup (needs root and iproute2):
#
#   PREFIX-r  the router host    192.0.2.1  (a bridge, the "switch", lives here)
#   PREFIX-l  the learner host   192.0.2.2
#   PREFIX-a  the actors host    192.0.2.3
#
# or, with mesh-up, two sites joined by their routers (deploy/README.md, "Router mesh"):
#
#   PREFIX-ra  site A: router A, the learner  192.0.2.1
#   PREFIX-rb  router B of site B             192.0.2.2 (to site A), 198.51.100.1 (to its actors)
#   PREFIX-ab  the actors of site B           198.51.100.2
#
# PREFIX-rb does not forward IP (a new namespace never does): the actors reach site A only
# through router B, as actors on a rack network that only its router leaves.
#
# Usage: deploy/netns.sh up|down|status|mesh-up|mesh-down|mesh-status [PREFIX]  (PREFIX: gvf)
# Then run each role with `ip netns exec PREFIX-x ...` (deploy/README.md, "Try it on one machine").
#
# 192.0.2.0/24 and 198.51.100.0/24 are TEST-NET-1 and -2 (RFC 5737), never routed; every
# interface and address is created inside the namespaces, none in the host's own network. `down`
# deletes the namespaces, which removes their interfaces and stops nothing else: end the
# processes started in them first.
set -euo pipefail

cmd=${1:-}
prefix=${2:-gvf}
subnet=192.0.2
roles=(r l a)
declare -A host=([r]=1 [l]=2 [a]=3)
if [[ $cmd == mesh-* ]]; then
    roles=(ra rb ab)
fi

exists() { ip netns list | awk '{print $1}' | grep -qx "$1"; }

up() {
    local ns
    trap 'echo "$0: setup failed, removing the namespaces" >&2; down' ERR
    for role in "${roles[@]}"; do
        ip netns add "$prefix-$role"
        ip -n "$prefix-$role" link set lo up
    done
    ns=$prefix-r
    ip -n "$ns" link add br0 type bridge
    ip -n "$ns" addr add "$subnet.${host[r]}/24" dev br0
    ip -n "$ns" link set br0 up
    for role in l a; do
        # a veth cable from the router's switch (port-ROLE) to the host's eth0, made in place
        ip -n "$ns" link add "port-$role" type veth peer name eth0 netns "$prefix-$role"
        ip -n "$ns" link set "port-$role" master br0 up
        ip -n "$prefix-$role" addr add "$subnet.${host[$role]}/24" dev eth0
        ip -n "$prefix-$role" link set eth0 up
    done
    status
}

mesh_up() {
    local a=$prefix-ra b=$prefix-rb actors=$prefix-ab
    trap 'echo "$0: setup failed, removing the namespaces" >&2; down' ERR
    for role in "${roles[@]}"; do
        ip netns add "$prefix-$role"
        ip -n "$prefix-$role" link set lo up
    done
    # the link between the sites: site A's eth0 to router B's to-a
    ip -n "$a" link add eth0 type veth peer name to-a netns "$b"
    ip -n "$a" addr add 192.0.2.1/24 dev eth0
    ip -n "$a" link set eth0 up
    ip -n "$b" addr add 192.0.2.2/24 dev to-a
    ip -n "$b" link set to-a up
    # site B's rack: router B's to-actors to the actors' eth0
    ip -n "$b" link add to-actors type veth peer name eth0 netns "$actors"
    ip -n "$b" addr add 198.51.100.1/24 dev to-actors
    ip -n "$b" link set to-actors up
    ip -n "$actors" addr add 198.51.100.2/24 dev eth0
    ip -n "$actors" link set eth0 up
    status
}

down() {
    for role in "${roles[@]}"; do
        if exists "$prefix-$role"; then
            ip netns del "$prefix-$role"
        fi
    done
}

status() {
    for role in "${roles[@]}"; do
        if exists "$prefix-$role"; then
            echo "$prefix-$role: $(ip -n "$prefix-$role" -br -4 addr show | awk '$1 != "lo" {print $1, $3}' | tr '\n' ' ')"
        else
            echo "$prefix-$role: absent"
        fi
    done
}

case $cmd in
    up) up ;;
    mesh-up) mesh_up ;;
    down | mesh-down) down ;;
    status | mesh-status) status ;;
    *) echo "usage: $0 up|down|status|mesh-up|mesh-down|mesh-status [PREFIX]" >&2; exit 2 ;;
esac
