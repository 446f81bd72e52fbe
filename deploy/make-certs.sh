#!/usr/bin/env bash
# Makes the certificates and Zenoh configs for a run whose actors live on
# other hosts: mutual TLS, and an access-control list by which each actor
# host may publish only under its own name. See `deploy/make-certs.sh --help`.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/make-certs.sh --dir DIR --run NAME --learner ADDR --hosts H1,H2,...

Writes, into DIR (created; existing files are not overwritten):
  ca.pem, ca-key.pem       a certificate authority for this run (keep ca-key.pem
                           private, or delete it once the hosts have theirs)
  learner.pem, learner-key.pem, learner.json5
                           the learner host's certificate and the Zenoh config
                           for `deploy/local.sh --listen tls/ADDR:PORT
                           --zenoh-config DIR/learner.json5`: mutual TLS, and an
                           access-control list by which host H may publish only
                           under afx/NAME/up/H/ and may ask for the run's config
                           and weights
  H.pem, H-key.pem, H.json5
                           each actor host's certificate (common name H) and its
                           Zenoh config for `deploy/actors.sh --host H
                           --zenoh-config H.json5`; copy these three files and
                           ca.pem to host H

Options:
  --dir DIR        where to write (paths in the configs are DIR's absolute path;
                   on another host, keep the same path or edit the config)
  --run NAME       the run's name (its run directory's name on the learner's host)
  --learner ADDR   the learner host's DNS name or IP address, as the actor hosts
                   will write it in --learner-at (repeatable)
  --hosts LIST     the actor hosts' names, comma-separated
  --days N         validity of the certificates (default 365)
  -h, --help       this help
Needs openssl.
USAGE
}

DIR="" RUN="" LEARNER=() HOSTS="" DAYS=365
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dir) DIR="${2:?--dir needs a directory}"; shift 2 ;;
    --run) RUN="${2:?--run needs a name}"; shift 2 ;;
    --learner) LEARNER+=("${2:?--learner needs a name or address}"); shift 2 ;;
    --hosts) HOSTS="${2:?--hosts needs a list}"; shift 2 ;;
    --days) DAYS="${2:?--days needs a number}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "make-certs.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ -n "$DIR" && -n "$RUN" && ${#LEARNER[@]} -gt 0 && -n "$HOSTS" ]] || { echo "make-certs.sh: --dir, --run, --learner and --hosts are required" >&2; usage >&2; exit 2; }
name_ok() { [[ "$1" =~ ^[A-Za-z0-9._-]{1,64}$ ]]; }
name_ok "$RUN" || { echo "make-certs.sh: --run '$RUN': letters, digits, '.', '_', '-' only" >&2; exit 2; }
IFS=, read -r -a HOST_LIST <<<"$HOSTS"
for h in "${HOST_LIST[@]}"; do
  name_ok "$h" || { echo "make-certs.sh: host '$h': letters, digits, '.', '_', '-' only" >&2; exit 2; }
  [[ "$h" != learner && "$h" != ca ]] || { echo "make-certs.sh: a host may not be called '$h'" >&2; exit 2; }
done
[[ "$DAYS" =~ ^[1-9][0-9]*$ ]] || { echo "make-certs.sh: --days needs a positive integer" >&2; exit 2; }
command -v openssl >/dev/null || { echo "make-certs.sh: openssl not found (apt-get install openssl)" >&2; exit 1; }
mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd)
for f in ca.pem learner.pem learner.json5; do
  [[ ! -e "$DIR/$f" ]] || { echo "make-certs.sh: $DIR/$f exists; use an empty directory" >&2; exit 2; }
done
umask 077

openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days "$DAYS" \
  -subj "/CN=afx-$RUN-ca" -keyout "$DIR/ca-key.pem" -out "$DIR/ca.pem" 2>/dev/null

# issue NAME SAN: a key and a certificate signed by the run's CA.
issue() {
  local name=$1 san=$2 usage=$3
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=$name" \
    -keyout "$DIR/$name-key.pem" -out "$DIR/$name.csr" 2>/dev/null
  printf 'subjectAltName=%s\nextendedKeyUsage=%s\nbasicConstraints=CA:FALSE\n' "$san" "$usage" >"$DIR/$name.ext"
  openssl x509 -req -in "$DIR/$name.csr" -CA "$DIR/ca.pem" -CAkey "$DIR/ca-key.pem" -CAcreateserial \
    -days "$DAYS" -extfile "$DIR/$name.ext" -out "$DIR/$name.pem" 2>/dev/null
  rm -f "$DIR/$name.csr" "$DIR/$name.ext"
}
SAN=""
for a in "${LEARNER[@]}"; do
  if [[ "$a" =~ ^[0-9.]+$ || "$a" == *:* ]]; then SAN+="${SAN:+,}IP:$a"; else SAN+="${SAN:+,}DNS:$a"; fi
done
issue learner "$SAN" serverAuth
for h in "${HOST_LIST[@]}"; do issue "$h" "DNS:$h" clientAuth; done
rm -f "$DIR/ca.srl"

# The learner's config: mutual TLS; each host publishes only under its own
# key and may ask for the run's config and weights; the learner's side may
# send weights, answers and its interests to every host.
{
  cat <<JSON
{
  // Written by deploy/make-certs.sh for run "$RUN". The gateway sets mode,
  // endpoints and link sizes itself; this file holds security only.
  transport: { link: { tls: {
    root_ca_certificate: "$DIR/ca.pem",
    listen_certificate: "$DIR/learner.pem",
    listen_private_key: "$DIR/learner-key.pem",
    enable_mtls: true,
  } } },
  access_control: {
    enabled: true,
    default_permission: "deny",
    rules: [
JSON
  for h in "${HOST_LIST[@]}"; do
    cat <<JSON
      { id: "publish-as-$h", messages: ["put"], flows: ["ingress"], permission: "allow",
        key_exprs: ["afx/$RUN/up/$h/*"] },
JSON
  done
  cat <<JSON
      { id: "ask", messages: ["query", "declare_subscriber"], flows: ["ingress"], permission: "allow",
        key_exprs: ["afx/$RUN/config", "afx/$RUN/weights"] },
      { id: "answer", messages: ["put", "reply", "declare_subscriber", "declare_queryable"],
        flows: ["egress"], permission: "allow", key_exprs: ["afx/$RUN/**"] },
    ],
    subjects: [
JSON
  for h in "${HOST_LIST[@]}"; do
    echo "      { id: \"$h\", cert_common_names: [\"$h\"] },"
  done
  echo "    ],"
  echo "    policies: ["
  for h in "${HOST_LIST[@]}"; do
    echo "      { rules: [\"publish-as-$h\", \"ask\", \"answer\"], subjects: [\"$h\"] },"
  done
  echo "    ],"
  echo "  },"
  echo "}"
} >"$DIR/learner.json5"

for h in "${HOST_LIST[@]}"; do
  cat >"$DIR/$h.json5" <<JSON
{
  // Written by deploy/make-certs.sh for host "$h" of run "$RUN".
  transport: { link: { tls: {
    root_ca_certificate: "$DIR/ca.pem",
    connect_certificate: "$DIR/$h.pem",
    connect_private_key: "$DIR/$h-key.pem",
    // Present this certificate to the learner's host (mutual TLS).
    enable_mtls: true,
  } } },
}
JSON
done
echo "wrote $DIR: ca.pem, learner.{pem,json5}, and for each of ${HOST_LIST[*]}: NAME.pem, NAME-key.pem, NAME.json5"
echo "learner host: deploy/local.sh ... --listen tls/${LEARNER[0]}:7447 --zenoh-config $DIR/learner.json5"
echo "actor host H: deploy/actors.sh --learner-at tls/${LEARNER[0]}:7447 --host H --zenoh-config $DIR/H.json5 ..."
