#!/usr/bin/env bash
# Make a small certificate authority and the certificates that Zenoh TLS / mutual TLS needs:
#
#   OUTDIR/ca.pem, ca.key          the CA (ca.key stays on the machine that signs; never distribute it)
#   OUTDIR/router.pem, router.key  the router's certificate: subjectAltName localhost, 127.0.0.1 and
#                                  every NAME given (DNS names, or IP addresses), serverAuth+clientAuth
#   OUTDIR/client.pem, client.key  a client certificate (clientAuth) that names no role: mTLS without
#                                  access control (router-tls.json5)
#   OUTDIR/learner.pem, evaluator.pem, operator.pem (+ .key)
#                                  one identity per role, common names gvf-learner, gvf-evaluator and
#                                  gvf-operator (gvfctl): what the access-control router config
#                                  (deploy/make_acl.py) grants rights to
#   OUTDIR/actor-NAME.pem, .key    one per actor NAME in $ACTORS (default "actor-0 actor-1"), common
#                                  name gvf-actor-NAME: an actor may publish only under its own name
#   OUTDIR/router-SITE.pem, .key   one per SITE in $ROUTERS (default none): the routers of a mesh, common
#                                  name gvf-router-SITE (make_acl.py --site, --upstream); subjectAltName the
#                                  loopback names and the site's own hosts: ROUTERS="a=hostA b=hostB,192.0.2.7"
#                                  (a site given without hosts gets the NAMEs), so that one site's router
#                                  key does not pass as another site's router
#
# Usage: [ACTORS="a0 a1 ..."] [ROUTERS="a[=HOST,...] b ..."] deploy/make_test_certs.sh OUTDIR [NAME ...]
#   e.g. ACTORS="h1-a0 h1-a1" deploy/make_test_certs.sh /etc/gvf/tls router.example.org 192.0.2.1
#
# NAME is how the learner and actors reach the router (the host of `transport.connect=[tls/NAME:7447]`):
# a client checks that the router's certificate names it (Zenoh's verify_name_on_connect).
# When OUTDIR already holds ca.pem and ca.key they are reused, so certificates made later (a router
# with new names) are trusted by clients that already have ca.pem. DAYS (default 365) sets validity.
#
# For tests and small clusters. Keys are ECDSA P-256 in PKCS#8 PEM, which rustls (Zenoh's TLS) reads.
set -euo pipefail

usage() { echo "usage: $0 OUTDIR [NAME ...]   (NAME: router hostname or IP address)" >&2; exit 2; }
[ $# -ge 1 ] || usage
case "$1" in -h|--help) usage ;; esac
command -v openssl >/dev/null || { echo "$0: openssl not found (apt-get install openssl)" >&2; exit 1; }

out=$1; shift
days=${DAYS:-365}
mkdir -p "$out"
umask 077  # private keys readable by their owner only
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# subjectAltName of a router: always the loopback names, plus each given name as an IP or a DNS entry
san_of() {
    local san="DNS:localhost,IP:127.0.0.1" name
    for name in "$@"; do
        if [[ $name =~ ^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$ || $name == *:* ]]; then
            san+=",IP:$name"
        else
            san+=",DNS:$name"
        fi
    done
    echo "$san"
}
san=$(san_of "$@")

newkey() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
serial() { echo "0x$(openssl rand -hex 16)"; }

if [ -s "$out/ca.pem" ] && [ -s "$out/ca.key" ]; then
    echo "reusing the CA in $out"
else
    newkey "$out/ca.key"
    openssl req -x509 -new -key "$out/ca.key" -sha256 -days "$days" -set_serial "$(serial)" \
        -subj "/CN=gvf test CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -addext "subjectKeyIdentifier=hash" \
        -out "$out/ca.pem"
fi

# sign NAME CN EXTENDED_KEY_USAGE [SAN]: OUTDIR/NAME.key and OUTDIR/NAME.pem signed by the CA
sign() {
    local name=$1 cn=$2 eku=$3 alt=${4:-}
    newkey "$out/$name.key"
    openssl req -new -key "$out/$name.key" -subj "/CN=$cn" -out "$tmp/$name.csr"
    {
        echo "basicConstraints=critical,CA:FALSE"
        echo "keyUsage=critical,digitalSignature,keyEncipherment"
        echo "extendedKeyUsage=$eku"
        echo "subjectKeyIdentifier=hash"
        echo "authorityKeyIdentifier=keyid,issuer"
        [ -z "$alt" ] || echo "subjectAltName=$alt"
    } >"$tmp/$name.ext"
    openssl x509 -req -in "$tmp/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" \
        -set_serial "$(serial)" -days "$days" -sha256 -extfile "$tmp/$name.ext" \
        -out "$out/$name.pem" 2>/dev/null
    openssl verify -CAfile "$out/ca.pem" "$out/$name.pem" >/dev/null
}

# the router also authenticates as a client when it connects to other routers (router_connect)
sign router gvf-router "serverAuth,clientAuth" "$san"
sign client gvf-client "clientAuth" "DNS:gvf-client"
for role in learner evaluator operator; do
    sign "$role" "gvf-$role" "clientAuth" "DNS:gvf-$role"
done
actors=${ACTORS:-actor-0 actor-1}
for name in $actors; do
    [[ $name =~ ^[A-Za-z0-9_.-]{1,64}$ ]] || { echo "$0: bad actor name $name" >&2; exit 2; }
    sign "actor-$name" "gvf-actor-$name" "clientAuth" "DNS:gvf-actor-$name"
done
for entry in ${ROUTERS:-}; do
    site=${entry%%=*}
    [[ $site =~ ^[A-Za-z0-9_.-]{1,64}$ ]] || { echo "$0: bad router site $site" >&2; exit 2; }
    if [[ $entry == *=* ]]; then
        IFS=, read -r -a hosts <<<"${entry#*=}"
        sign "router-$site" "gvf-router-$site" "serverAuth,clientAuth" "$(san_of "${hosts[@]}")"
    else
        sign "router-$site" "gvf-router-$site" "serverAuth,clientAuth" "$san"
    fi
done
chmod 644 "$out"/*.pem

echo "wrote $out/{ca,router,client,learner,evaluator,operator}.{pem,key} and actor-{${actors// /,}}.{pem,key}; router names: $san"
