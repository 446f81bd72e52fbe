#!/usr/bin/env bash
# Starts one learner and N actors on this host, supervises the actors, and shuts
# everything down cleanly on Ctrl-C. See `deploy/local.sh --help`.
set -euo pipefail
# The whole script is one block, read before it runs: editing the file
# while a run is under way cannot change what this run executes.
{

usage() {
  cat <<'USAGE'
Usage: deploy/local.sh --actors N [options] [-- extra learner args]

Builds release binaries, starts the learner, then N actors; restarts an actor
that exits abnormally (with back-off); prints the metrics URL; on Ctrl-C stops
actors, then the learner (which writes a final checkpoint), and removes
shared-memory resources.

Options:
  --actors N        number of actor processes on this host (required; 0 only
                    with --listen, when every actor runs on other hosts)
  --envs-per-actor K
                    environments each actor steps side by side (default 1): a
                    thread each, the U-Net and policy batched over them; use it
                    to fill a GPU, or the cores of a big CPU with fewer processes
  --run-dir DIR     run directory (config, checkpoints, logs); default runs/run-<time>
  --resume          resume the run in --run-dir from its newest valid checkpoint
  --method M        ours (default: object-level map), nomap-seg, nomap-noseg
                    or intexp (no map: GRU memory, point labels; see README, "The methods")
  --env ENV         sim (default: simulator, map, U-Net, labeler) or
                    bandit-fixture (a wiring test fixture)
  --image-size N    camera and map side in pixels, a multiple of 16 (default 128,
                    the paper's; 64 runs about 4x faster on a small CPU)
  --episode-steps N steps per episode (default 600, the paper's)
  --data DIR        shared data (iTHOR rooms, object catalogue); default ../shared/data
  --scenes S        ithor (the 20 training rooms, default) or generated
  --renderer R      auto (default: gpu when a Vulkan adapter exists, else cpu),
                    gpu (wgpu: a GPU or Mesa lavapipe) or cpu (ray casting)
  --record DIR      each actor records episodes as MCAP files for Foxglove in
                    DIR (actorN_step<run steps>_episode<id>.mcap; never overwritten)
  --record-every N  with --record, only every N-th episode (default 1)
  --dataset DIR     each actor writes the label ladder's dataset to DIR (method
                    ours; for learner train-unet, docs/ladder.md): frames with
                    ground-truth, tried-truth and the run's own labels
  --dataset-every N with --dataset, only every N-th episode (default 1)
  --dataset-frame-every K
                    with --dataset, every K-th frame of an episode (default 1)
  --device D        where learner and actors run the networks: cpu (default) or
                    gpu (binaries built with --features nets/gpu; see docs/running.md)
  --max-steps N     stop as on Ctrl-C (final checkpoint) once the run has taken
                    N environment steps over all actors (on --resume: the run's
                    total, so resuming continues to N); the run directory keeps
                    it, so --resume without it continues to the same N;
                    default: run until stopped
  --max-seconds S   stop as on Ctrl-C (final checkpoint) S seconds after the
                    learner started (building not counted): for a machine lent
                    for a fixed time, leave a minute or two of it for the stop
                    and deploy/pack-run.sh; default: no deadline
  --seed N          the run's seed (default 0): initial networks, rooms, actions;
                    runs that differ only in --seed are independent repeats
  --port PORT       HTTP port of the learner's metrics endpoint (default 9464)
  --progress-every S
                    print a progress line every S seconds (default 10; 0 = every
                    poll, about 2 s): steps and steps/s, mean return and
                    interaction success of the last 100 episodes, the U-Net's
                    validation IoU, PPO's KL and entropy, actors alive,
                    messages dropped, time to --max-steps
  --listen ENDPOINT also start a gateway for actors on other hosts, listening
                    on ENDPOINT: tls/ADDR:PORT (certificates in --zenoh-config)
                    or tcp/ADDR:PORT (plain: only on a network you trust); ADDR
                    is an address of this host. Other hosts then run
                    deploy/actors.sh (the script prints the command)
  --remote-actors M actor ids kept for other hosts (default 0; with --listen):
                    ids N .. N+M-1, given out with deploy/actors.sh's
                    --first-actor-id
  --zenoh-config FILE
                    the gateway's Zenoh config (JSON5): TLS certificates,
                    mutual TLS, access control; deploy/make-certs.sh writes one
  --actor-nice N    run the actors at niceness N, 0..19 (default 10): where
                    they fill every core, the learner's receive loop and
                    training threads still run first, so its buffers
                    overflow less and the U-Net trains its [unet]
                    steps_per_episode for every episode; 0 runs them at
                    the script's own
  --training-nice N the learner's training threads (PPO, U-Net) at niceness
                    N, 0..19 (default 0: before the actors; on a machine
                    too small for both the actors take what is left, fewer
                    steps per second, docs/decisions/0013-unet-steps-per-
                    episode.md). --training-nice 10 with the default
                    --actor-nice shares the CPU between them as at one
                    priority
  --debug           use debug builds (faster to build, slower to run)
  --bin-dir DIR     use the learner and actor binaries in DIR; build nothing
  -h, --help        this help
--envs-per-actor, --data, --scenes, --renderer and --device are saved in the
run's config.toml ([actors]), where every actor reads them; on --resume the
saved ones hold unless given again.
Everything after `--` is passed to `learner serve`, e.g. `-- --config my.toml`
for a learner config (reward weights: [task.reward]; see docs/running.md).
Stop with Ctrl-C, or with SIGTERM (a script started in the background with `&`
ignores SIGINT).
USAGE
}

PROGRESS_EVERY=10
ACTORS="" ENVS="" RUN_DIR="" RESUME=0 PORT=9464 PROFILE=release BIN="" SEED=0 MAX_STEPS= MAX_SECONDS=
# TASK_ARGS: what the run learns (fixed once the run exists); SETTINGS: how
# its actors run, written into the run's config.toml ([actors]) by the
# learner and read from there by every actor; RECORD_ARGS: this start's
# recording, given to the actors directly.
TASK_ARGS=() SETTINGS=() RECORD_ARGS=() LEARNER_DEVICE=() METHOD=ours ENV_KIND=sim
LISTEN="" REMOTE=0 ZENOH_CONFIG=() ACTOR_NICE=10 TRAINING_NICE=
EXTRA=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --actors) ACTORS="${2:?--actors needs a number}"; shift 2 ;;
    --envs-per-actor) ENVS="${2:?--envs-per-actor needs a number}"; SETTINGS+=(--set "actors.envs=$ENVS"); shift 2 ;;
    --run-dir) RUN_DIR="${2:?--run-dir needs a directory}"; shift 2 ;;
    --resume) RESUME=1; shift ;;
    --method) METHOD="${2:?--method needs a value}"; TASK_ARGS+=(--method "$METHOD"); shift 2 ;;
    --env) ENV_KIND="${2:?--env needs a value}"; TASK_ARGS+=(--env "$ENV_KIND"); shift 2 ;;
    --image-size) TASK_ARGS+=(--image-size "${2:?--image-size needs a number}"); shift 2 ;;
    --episode-steps) TASK_ARGS+=(--episode-steps "${2:?--episode-steps needs a number}"); shift 2 ;;
    --data) SETTINGS+=(--set "actors.data=$(cd "${2:?--data needs a directory}" && pwd)"); shift 2 ;;
    --scenes) SETTINGS+=(--set "actors.scenes=${2:?--scenes needs a value}"); shift 2 ;;
    --renderer) SETTINGS+=(--set "actors.renderer=${2:?--renderer needs a value}"); shift 2 ;;
    --record) mkdir -p "${2:?--record needs a directory}"; RECORD_ARGS+=(--record "$(cd "$2" && pwd)"); shift 2 ;;
    --record-every) RECORD_ARGS+=(--record-every "${2:?--record-every needs a number}"); shift 2 ;;
    --dataset) mkdir -p "${2:?--dataset needs a directory}"; RECORD_ARGS+=(--dataset "$(cd "$2" && pwd)"); shift 2 ;;
    --dataset-every) RECORD_ARGS+=(--dataset-every "${2:?--dataset-every needs a number}"); shift 2 ;;
    --dataset-frame-every) RECORD_ARGS+=(--dataset-frame-every "${2:?--dataset-frame-every needs a number}"); shift 2 ;;
    --device) DEVICE="${2:?--device needs a value}"; SETTINGS+=(--set "actors.device=$DEVICE"); LEARNER_DEVICE=(--device "$DEVICE"); shift 2 ;;
    --port) PORT="${2:?--port needs a number}"; shift 2 ;;
    --progress-every) PROGRESS_EVERY="${2:?--progress-every needs a number of seconds}"; shift 2 ;;
    --max-steps) MAX_STEPS="${2:?--max-steps needs a number}"; shift 2 ;;
    --max-seconds) MAX_SECONDS="${2:?--max-seconds needs a number of seconds}"; shift 2 ;;
    --seed) SEED="${2:?--seed needs a number}"; TASK_ARGS+=(--seed "$SEED"); shift 2 ;;
    --listen) LISTEN="${2:?--listen needs an endpoint, e.g. tls/10.0.0.5:7447}"; shift 2 ;;
    --remote-actors) REMOTE="${2:?--remote-actors needs a number}"; shift 2 ;;
    --zenoh-config) ZENOH_CONFIG=(--zenoh-config "$(cd "$(dirname "${2:?--zenoh-config needs a file}")" && pwd)/$(basename "$2")"); shift 2 ;;
    --actor-nice) ACTOR_NICE="${2:?--actor-nice needs a number}"; shift 2 ;;
    --training-nice) TRAINING_NICE="${2:?--training-nice needs a number}"; shift 2 ;;
    --debug) PROFILE=debug; shift ;;
    --bin-dir) BIN="$(cd "${2:?--bin-dir needs a directory}" && pwd)"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; EXTRA=("$@"); break ;;
    *) echo "local.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ "$REMOTE" =~ ^[0-9]+$ ]] || { echo "local.sh: --remote-actors needs a non-negative integer, got '$REMOTE'" >&2; exit 2; }
if [[ -n "$LISTEN" ]]; then
  [[ "$LISTEN" =~ ^(tcp|tls)/.+:[0-9]+$ ]] || { echo "local.sh: --listen needs tls/ADDR:PORT or tcp/ADDR:PORT, got '$LISTEN'" >&2; exit 2; }
  [[ "$REMOTE" -gt 0 ]] || { echo "local.sh: --listen needs --remote-actors M (M >= 1): the actor ids other hosts may use" >&2; exit 2; }
  [[ "$ACTORS" =~ ^[0-9]+$ ]] || { echo "local.sh: --actors N is required (N >= 0 with --listen)" >&2; usage >&2; exit 2; }
else
  [[ "$REMOTE" -eq 0 && ${#ZENOH_CONFIG[@]} -eq 0 ]] || { echo "local.sh: --remote-actors and --zenoh-config need --listen ENDPOINT" >&2; exit 2; }
  [[ "$ACTORS" =~ ^[1-9][0-9]*$ ]] || { echo "local.sh: --actors N is required (N >= 1)" >&2; usage >&2; exit 2; }
fi
ALL_ACTORS=$((ACTORS + REMOTE))
[[ -z "$ENVS" || ( "$ENVS" =~ ^[1-9][0-9]*$ && "$ENVS" -le 256 ) ]] || { echo "local.sh: --envs-per-actor needs an integer in 1..256, got '$ENVS'" >&2; exit 2; }
[[ -z "$MAX_STEPS" || "$MAX_STEPS" =~ ^[1-9][0-9]*$ ]] || { echo "local.sh: --max-steps needs a positive integer, got '$MAX_STEPS'" >&2; exit 2; }
[[ -z "$MAX_SECONDS" || "$MAX_SECONDS" =~ ^[1-9][0-9]*$ ]] || { echo "local.sh: --max-seconds needs a positive whole number of seconds, got '$MAX_SECONDS'" >&2; exit 2; }
[[ "$ACTOR_NICE" =~ ^[0-9]+$ && "$ACTOR_NICE" -le 19 ]] || { echo "local.sh: --actor-nice needs an integer in 0..19, got '$ACTOR_NICE'" >&2; exit 2; }
TRAINING_NICE="${TRAINING_NICE:-0}"
[[ "$TRAINING_NICE" =~ ^[0-9]+$ && "$TRAINING_NICE" -le 19 ]] || { echo "local.sh: --training-nice needs an integer in 0..19, got '$TRAINING_NICE'" >&2; exit 2; }
[[ "$SEED" =~ ^[0-9]+$ ]] || { echo "local.sh: --seed needs a non-negative integer, got '$SEED'" >&2; exit 2; }
[[ "$PROGRESS_EVERY" =~ ^[0-9]+$ ]] || { echo "local.sh: --progress-every needs a whole number of seconds, got '$PROGRESS_EVERY'" >&2; exit 2; }
if [[ $RESUME -eq 1 && -z "$RUN_DIR" ]]; then
  echo "local.sh: --resume needs --run-dir DIR (the run to resume)" >&2; exit 2
fi

cd "$(dirname "$0")/.."
# without_backtrace, supervise, wait_gone
source deploy/supervise.sh
REPO=$(pwd)

# System packages this script needs.
missing=()
for cmd_pkg in curl:curl; do
  command -v "${cmd_pkg%%:*}" >/dev/null 2>&1 || missing+=("${cmd_pkg##*:}")
done
if [[ ${#missing[@]} -gt 0 ]]; then
  if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null; then
    echo "installing: ${missing[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "local.sh: missing packages: ${missing[*]} (install them: sudo apt-get install ${missing[*]})" >&2; exit 1
  fi
fi
if [[ -n "$BIN" ]]; then
  for b in learner actor ${LISTEN:+gateway}; do
    [[ -x "$BIN/$b" ]] || { echo "local.sh: --bin-dir $BIN has no executable $b" >&2; exit 2; }
  done
else
  command -v cargo >/dev/null || { echo "local.sh: cargo not found: install Rust from https://rustup.rs" >&2; exit 1; }
  echo "building $PROFILE binaries..."
  if [[ $PROFILE == release ]]; then
    cargo build --release -p learner -p actor ${LISTEN:+-p gateway}
  else
    cargo build -p learner -p actor ${LISTEN:+-p gateway}
  fi
  TARGET_DIR=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])' 2>/dev/null || echo "$REPO/target")
  BIN="$TARGET_DIR/$PROFILE"
fi

source deploy/libtorch-path.sh
use_libtorch_of_python "$BIN/actor" || exit 1

[[ -n "$RUN_DIR" ]] || RUN_DIR="runs/run-$(date -u +%Y%m%dT%H%M%SZ)"
mkdir -p "$RUN_DIR/logs"
RUN_DIR=$(cd "$RUN_DIR" && pwd)
LOGS="$RUN_DIR/logs"
PREFIX="afx-$(basename "$RUN_DIR" | tr -cd 'A-Za-z0-9_-')"
STOP_FILE="$LOGS/.stopping"
# The run's --max-steps, kept for --resume (a resumed run without the flag
# continues to the same total rather than past it).
MAX_STEPS_FILE="$RUN_DIR/max-steps"
if [[ $RESUME -eq 1 && -z "$MAX_STEPS" && -s "$MAX_STEPS_FILE" ]]; then
  MAX_STEPS=$(<"$MAX_STEPS_FILE")
  [[ "$MAX_STEPS" =~ ^[1-9][0-9]*$ ]] || { echo "local.sh: $MAX_STEPS_FILE holds '$MAX_STEPS', not a step count: delete it or give --max-steps N" >&2; exit 2; }
  echo "resuming to the run's --max-steps $MAX_STEPS (from $MAX_STEPS_FILE; give --max-steps N to change it)"
fi
[[ -z "$MAX_STEPS" ]] || echo "$MAX_STEPS" >"$MAX_STEPS_FILE"
rm -f "$STOP_FILE" "$RUN_DIR/http.addr"

# The learner's training threads at --training-nice (0 by default: with its
# receive loop, before the actors; learner/src/thread_priority.rs).
LEARNER_ARGS=(serve --service-prefix "$PREFIX" --max-actors "$ALL_ACTORS" --http-addr "127.0.0.1:$PORT" "${LEARNER_DEVICE[@]}" "${SETTINGS[@]}" --set "training_nice=$TRAINING_NICE")
if [[ $RESUME -eq 1 ]]; then
  [[ ${#TASK_ARGS[@]} -eq 0 ]] || echo "local.sh: resuming: the run's saved task is used; ignoring ${TASK_ARGS[*]}" >&2
  LEARNER_ARGS+=(--resume "$RUN_DIR")
else
  LEARNER_ARGS+=(--run-dir "$RUN_DIR" "${TASK_ARGS[@]}")
fi
echo "starting the learner (log: $LOGS/learner.log)"
"$BIN/learner" "${LEARNER_ARGS[@]}" "${EXTRA[@]}" >>"$LOGS/learner.log" 2>&1 &
LEARNER_PID=$!
LEARNER_STARTED_S=$SECONDS
echo "$LEARNER_PID" >"$LOGS/learner.pid"

for _ in $(seq 1 200); do
  [[ -s "$RUN_DIR/http.addr" ]] && break
  if ! kill -0 "$LEARNER_PID" 2>/dev/null; then
    echo "local.sh: the learner exited at start:" >&2
    without_backtrace <"$LOGS/learner.log" | tail -n 20 >&2
    if without_backtrace <"$LOGS/learner.log" | tail -n 20 | grep -q "Address already in use"; then
      echo "local.sh: port $PORT is taken (another run's learner?): pick a free one with --port" >&2
    fi
    exit 1
  fi
  sleep 0.1
done
[[ -s "$RUN_DIR/http.addr" ]] || { echo "local.sh: the learner did not come up; see $LOGS/learner.log" >&2; kill "$LEARNER_PID"; exit 1; }
ADDR=$(cat "$RUN_DIR/http.addr")
curl -fsS --retry 20 --retry-delay 0 --retry-connrefused "http://$ADDR/healthz" >/dev/null \
  || { echo "local.sh: the learner's endpoint http://$ADDR does not answer; see $LOGS/learner.log" >&2; kill "$LEARNER_PID"; exit 1; }

SETUP_FAILED="$LOGS/.setup-failed"
rm -f "$SETUP_FAILED"
SUPERVISORS=()
for ((i = 0; i < ACTORS; i++)); do
  supervise "actor-$i" "actor $i" "got policy version" "before it received its first weights" \
    nice -n "$ACTOR_NICE" "$BIN/actor" --actor-id "$i" --learner "$PREFIX" --config "$RUN_DIR/config.toml" "${RECORD_ARGS[@]}" &
  SUPERVISORS+=($!)
done
# The gateway for other hosts' actors, restarted like an actor; one that
# exits before it is ready (a taken port, a bad certificate) stops the run.
GATEWAY_SUPERVISOR=()
if [[ -n "$LISTEN" ]]; then
  supervise gateway "the gateway" "gateway ready" "before it was ready" \
    "$BIN/gateway" learner-host --run-dir "$RUN_DIR" --listen "$LISTEN" "${ZENOH_CONFIG[@]}" &
  GATEWAY_SUPERVISOR=($!)
fi

stop_gateway() {
  [[ ${#GATEWAY_SUPERVISOR[@]} -gt 0 ]] || return 0
  [[ -s "$LOGS/gateway.pid" ]] && kill -INT "$(cat "$LOGS/gateway.pid")" 2>/dev/null || true
  wait_gone "${GATEWAY_SUPERVISOR[@]}"
}

shutdown() {
  trap - INT TERM
  echo; echo "stopping: actors first, then the learner (final checkpoint)..."
  touch "$STOP_FILE"
  for ((i = 0; i < ACTORS; i++)); do
    [[ -s "$LOGS/actor-$i.pid" ]] && kill -INT "$(cat "$LOGS/actor-$i.pid")" 2>/dev/null || true
  done
  wait_gone "${SUPERVISORS[@]}"
  stop_gateway
  kill -INT "$LEARNER_PID" 2>/dev/null || true
  local code=0; wait "$LEARNER_PID" || code=$?
  "$BIN/learner" clean >/dev/null 2>&1 || true
  rm -f "$STOP_FILE" "$LOGS"/actor-*.pid "$LOGS/learner.pid" "$LOGS/gateway.pid"
  echo "stopped (learner exit status $code). Resume with: deploy/local.sh --actors $ACTORS --run-dir $RUN_DIR --resume${LISTEN:+ --listen $LISTEN --remote-actors $REMOTE}"
  [[ ! -e "$SETUP_FAILED" ]] || code=1
  exit "$code"
}
trap shutdown INT TERM

echo "run:      $RUN_DIR"
echo "live:     http://$ADDR/   (training curves, actors, config; open in a browser)"
echo "metrics:  http://$ADDR/metrics"
echo "status:   http://$ADDR/api/status   (curl -s http://$ADDR/api/status)"
echo "actors:   $ACTORS x $ENV_KIND ($METHOD), logs in $LOGS; Ctrl-C to stop"
echo "curves:   $BIN/learner plot --run-dir $RUN_DIR"
if [[ -n "$LISTEN" ]]; then
  echo "gateway:  $LISTEN for actor ids $ACTORS..$((ALL_ACTORS - 1)) on other hosts (log: $LOGS/gateway.log). On each,"
  echo "          with a copy of $RUN_DIR/join.key (the run's secret) in DIR and the learner's address in place of ${LISTEN#*/}:"
  echo "          deploy/actors.sh --learner-at $LISTEN --run $(basename "$RUN_DIR") --run-dir DIR --first-actor-id $ACTORS --actors K"
fi

# Environment steps of the whole run, from the learner's status (empty if it
# does not answer).
run_steps() {
  curl -fsS --max-time 5 "http://$ADDR/api/status" 2>/dev/null | grep -o '"env_steps":[0-9]*' | head -n 1 | cut -d: -f2
}

# One progress line from the learner's status and its last 100 episodes;
# prints the line, then "steps seconds" for the next line's rate.
PROGRESS_PY='
import datetime, json, sys
status = json.loads(sys.stdin.readline())
history = json.loads(sys.stdin.readline() or "{}")
actors, max_steps, now, last_steps, last_s = sys.argv[1:6]
now, last_s = float(now), float(last_s)
steps = int(status.get("env_steps") or 0)
rate = (steps - int(last_steps)) / (now - last_s) if last_steps and now > last_s else None
episodes = [r.get("stats") or {} for r in history.get("records") or []]
def mean(key):
    v = [e[key] for e in episodes if isinstance(e.get(key), (int, float))]
    return sum(v) / len(v) if v else None
def f(x, digits=2):
    return "-" if x is None else "%.*f" % (digits, x)
unet, update = status.get("last_unet") or {}, status.get("last_update") or {}
parts = ["%d steps%s" % (steps, "" if rate is None else " (%.0f/s)" % rate),
         "last %d episodes: return %s, success %s" % (len(episodes),
             f(mean("episode_return"), 1), f(mean("interaction_success_rate"))),
         "U-Net val IoU %s" % f(unet.get("deployed_iou")),
         "PPO KL %s, entropy %s" % (f(update.get("approx_kl"), 4), f(update.get("entropy"))),
         "actors %s/%s" % (status.get("actors_alive", 0), actors),
         "dropped %s" % status.get("dropped", 0)]
if int(max_steps) > 0 and rate:
    left = max(int(max_steps) - steps, 0) / rate
    parts.append("%dh%02dm to --max-steps" % (left // 3600, left % 3600 // 60))
print(datetime.datetime.now().strftime("%H:%M:%S"), " | ".join(parts))
print(steps, now)
'
LAST_PROGRESS_S=$SECONDS LAST_STEPS="" LAST_STEPS_S=0
[[ $PROGRESS_EVERY -gt 0 ]] || LAST_PROGRESS_S=-1
print_progress() {
  local status history out
  status=$(curl -fsS --max-time 5 "http://$ADDR/api/status" 2>/dev/null) || return 0
  history=$(curl -fsS --max-time 5 "http://$ADDR/api/history?kind=episode&last=100" 2>/dev/null) || history='{}'
  out=$({ printf '%s\n' "$status"; printf '%s\n' "$history"; } \
    | python3 -c "$PROGRESS_PY" "$ALL_ACTORS" "${MAX_STEPS:-0}" "$SECONDS" "$LAST_STEPS" "$LAST_STEPS_S" 2>/dev/null) || return 0
  echo "${out%$'\n'*}"
  read -r LAST_STEPS LAST_STEPS_S <<<"${out##*$'\n'}"
}

[[ -z "$MAX_STEPS" ]] || echo "stops after $MAX_STEPS environment steps"
[[ -z "$MAX_SECONDS" ]] || echo "stops $MAX_SECONDS s after the learner started"
while kill -0 "$LEARNER_PID" 2>/dev/null; do
  if [[ -e "$SETUP_FAILED" ]]; then
    echo "local.sh: stopping the run: fix the problem above, then start it again" >&2
    shutdown
  fi
  if [[ $((SECONDS - LAST_PROGRESS_S)) -ge $PROGRESS_EVERY ]]; then
    LAST_PROGRESS_S=$SECONDS
    print_progress
  fi
  if [[ -n "$MAX_STEPS" ]]; then
    steps=$(run_steps || true)
    if [[ -n "$steps" && "$steps" -ge "$MAX_STEPS" ]]; then
      echo "the run reached $steps environment steps (--max-steps $MAX_STEPS)"
      shutdown
    fi
  fi
  if [[ -n "$MAX_SECONDS" && $((SECONDS - LEARNER_STARTED_S)) -ge $MAX_SECONDS ]]; then
    echo "the run reached its deadline (--max-seconds $MAX_SECONDS) at $(run_steps || echo '?') environment steps"
    shutdown
  fi
  # `wait` on a background sleep lets a Ctrl-C's trap run at once.
  sleep 2 & wait $! || true
done
code=0; wait "$LEARNER_PID" || code=$?
if [[ ! -e "$STOP_FILE" ]]; then
  echo "local.sh: the learner exited unexpectedly (status $code); see $LOGS/learner.log" >&2
  touch "$STOP_FILE"
  for ((i = 0; i < ACTORS; i++)); do
    [[ -s "$LOGS/actor-$i.pid" ]] && kill -INT "$(cat "$LOGS/actor-$i.pid")" 2>/dev/null || true
  done
  wait_gone "${SUPERVISORS[@]}"
  stop_gateway
  "$BIN/learner" clean >/dev/null 2>&1 || true
  exit 1
fi
exit
}
