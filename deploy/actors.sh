#!/usr/bin/env bash
# Starts a gateway and N actors on an actor host of a run whose learner runs
# on another host (deploy/local.sh --listen there). See `deploy/actors.sh --help`.
set -euo pipefail
# Read whole before it runs, like local.sh: editing the file cannot change a running script.
{

usage() {
  cat <<'USAGE'
Usage: deploy/actors.sh --learner-at ENDPOINT --run NAME --run-dir DIR --first-actor-id I --actors K [options]

On an actor host: starts the gateway to the learner's host, waits for the
run's config from there, then starts K actors (ids I .. I+K-1) and restarts
one that exits abnormally (with back-off); Ctrl-C (or SIGTERM) stops the
actors, then the gateway. The learner's host runs deploy/local.sh --listen,
which prints this command with its values.

Required:
  --learner-at ENDPOINT  the learner host's gateway: tls/HOST:PORT or tcp/HOST:PORT
  --run NAME             the run's name (its run directory's name on the learner's host)
  --run-dir DIR          this host's directory for the run: the run's config.toml
                         is written here, logs go to DIR/logs; copy the learner's
                         RUN_DIR/join.key here first (it is the run's secret)
  --first-actor-id I     the first of this host's actor ids: hosts must not overlap,
                         and ids must be below the learner's --actors + --remote-actors
  --actors K             actor processes on this host

Options:
  --host NAME            this host's name in the run (default: the system's host name)
  --zenoh-config FILE    the gateway's Zenoh config (JSON5): TLS certificates;
                         deploy/make-certs.sh writes one per host
  --data DIR             shared data on this host (default: the run's [actors] data)
  --envs-per-actor K     environments each actor steps (default: the run's)
  --device D             cpu or gpu (default: the run's)
  --service-prefix P     this host's shared-memory prefix (default: the run's); two
                         "hosts" on one machine need different ones
  --bin-dir DIR          use the gateway and actor binaries in DIR; build nothing
  --debug                use debug builds
  -h, --help             this help
USAGE
}

LEARNER_AT="" RUN="" RUN_DIR="" FIRST="" ACTORS="" HOST_ARGS=() ZENOH_CONFIG=() ACTOR_ARGS=()
PREFIX_ARGS=() BIN="" PROFILE=release
while [[ $# -gt 0 ]]; do
  case "$1" in
    --learner-at) LEARNER_AT="${2:?--learner-at needs an endpoint}"; shift 2 ;;
    --run) RUN="${2:?--run needs a name}"; shift 2 ;;
    --run-dir) RUN_DIR="${2:?--run-dir needs a directory}"; shift 2 ;;
    --first-actor-id) FIRST="${2:?--first-actor-id needs a number}"; shift 2 ;;
    --actors) ACTORS="${2:?--actors needs a number}"; shift 2 ;;
    --host) HOST_ARGS=(--host "${2:?--host needs a name}"); shift 2 ;;
    --zenoh-config) ZENOH_CONFIG=(--zenoh-config "$(cd "$(dirname "${2:?--zenoh-config needs a file}")" && pwd)/$(basename "$2")"); shift 2 ;;
    --data) ACTOR_ARGS+=(--data "$(cd "${2:?--data needs a directory}" && pwd)"); shift 2 ;;
    --envs-per-actor) ACTOR_ARGS+=(--envs "${2:?--envs-per-actor needs a number}"); shift 2 ;;
    --device) ACTOR_ARGS+=(--device "${2:?--device needs a value}"); shift 2 ;;
    --service-prefix) PREFIX_ARGS=(--service-prefix "${2:?--service-prefix needs a prefix}"); shift 2 ;;
    --bin-dir) BIN="$(cd "${2:?--bin-dir needs a directory}" && pwd)"; shift 2 ;;
    --debug) PROFILE=debug; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "actors.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
for required in LEARNER_AT:--learner-at RUN:--run RUN_DIR:--run-dir FIRST:--first-actor-id ACTORS:--actors; do
  var=${required%%:*}
  [[ -n "${!var}" ]] || { echo "actors.sh: ${required#*:} is required" >&2; usage >&2; exit 2; }
done
[[ "$LEARNER_AT" =~ ^(tcp|tls)/.+:[0-9]+$ ]] || { echo "actors.sh: --learner-at needs tls/HOST:PORT or tcp/HOST:PORT, got '$LEARNER_AT'" >&2; exit 2; }
[[ "$FIRST" =~ ^[0-9]+$ ]] || { echo "actors.sh: --first-actor-id needs a non-negative integer, got '$FIRST'" >&2; exit 2; }
[[ "$ACTORS" =~ ^[1-9][0-9]*$ ]] || { echo "actors.sh: --actors needs a positive integer, got '$ACTORS'" >&2; exit 2; }
mkdir -p "$RUN_DIR/logs"
RUN_DIR=$(cd "$RUN_DIR" && pwd)
LOGS="$RUN_DIR/logs"
[[ -s "$RUN_DIR/join.key" ]] || { echo "actors.sh: $RUN_DIR/join.key is missing: copy the learner's RUN_DIR/join.key there (the run's secret; keep it private)" >&2; exit 2; }

cd "$(dirname "$0")/.."
# without_backtrace, supervise, wait_gone
source deploy/supervise.sh
if [[ -n "$BIN" ]]; then
  for b in gateway actor; do
    [[ -x "$BIN/$b" ]] || { echo "actors.sh: --bin-dir $BIN has no executable $b" >&2; exit 2; }
  done
else
  command -v cargo >/dev/null || { echo "actors.sh: cargo not found: install Rust from https://rustup.rs" >&2; exit 1; }
  echo "building $PROFILE binaries..."
  if [[ $PROFILE == release ]]; then cargo build --release -p gateway -p actor; else cargo build -p gateway -p actor; fi
  TARGET_DIR=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])' 2>/dev/null || echo "$(pwd)/target")
  BIN="$TARGET_DIR/$PROFILE"
fi

source deploy/libtorch-path.sh
use_libtorch_of_python "$BIN/actor" || exit 1

STOP_FILE="$LOGS/.stopping" SETUP_FAILED="$LOGS/.setup-failed"
rm -f "$STOP_FILE" "$SETUP_FAILED" "$RUN_DIR/config.toml"

echo "starting the gateway to $LEARNER_AT (log: $LOGS/gateway.log)"
supervise gateway "the gateway" "the run's config arrived" "before it was ready" "$BIN/gateway" actor-host --learner-at "$LEARNER_AT" --run "$RUN" \
  --run-dir "$RUN_DIR" "${HOST_ARGS[@]}" "${PREFIX_ARGS[@]}" "${ZENOH_CONFIG[@]}" &
GATEWAY_SUPERVISOR=$!
ACTOR_SUPERVISORS=()

shutdown() {
  trap - INT TERM
  echo; echo "stopping: actors first, then the gateway..."
  touch "$STOP_FILE"
  for pidfile in "$LOGS"/actor-*.pid; do
    [[ -s "$pidfile" ]] && kill -INT "$(cat "$pidfile")" 2>/dev/null || true
  done
  wait_gone "${ACTOR_SUPERVISORS[@]}"
  [[ -s "$LOGS/gateway.pid" ]] && kill -INT "$(cat "$LOGS/gateway.pid")" 2>/dev/null || true
  wait_gone "$GATEWAY_SUPERVISOR"
  rm -f "$STOP_FILE" "$LOGS"/*.pid
  local code=0
  [[ ! -e "$SETUP_FAILED" ]] || code=1
  echo "stopped"
  exit "$code"
}
trap shutdown INT TERM

echo "waiting for the run's config from the learner's host..."
until [[ -s "$RUN_DIR/config.toml" ]]; do
  [[ -e "$SETUP_FAILED" ]] && shutdown
  sleep 0.5 & wait $! || true
done
for ((id = FIRST; id < FIRST + ACTORS; id++)); do
  supervise "actor-$id" "actor $id" "got policy version" "before it received its first weights" "$BIN/actor" --actor-id "$id" --config "$RUN_DIR/config.toml" "${ACTOR_ARGS[@]}" &
  ACTOR_SUPERVISORS+=($!)
done
echo "actors $FIRST..$((FIRST + ACTORS - 1)) started (logs in $LOGS); the learner's status lists this host under remote_hosts; Ctrl-C to stop"
while kill -0 "$GATEWAY_SUPERVISOR" 2>/dev/null; do
  [[ -e "$SETUP_FAILED" ]] && shutdown
  sleep 2 & wait $! || true
done
echo "actors.sh: the gateway's supervisor ended; stopping" >&2
touch "$SETUP_FAILED"
shutdown
}
