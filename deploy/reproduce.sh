#!/usr/bin/env bash
# Trains every (method, seed) with one budget, chooses each run's checkpoint
# on the validation rooms, scores it once on the test rooms, and writes the
# comparison page. Resumable: rerun the same command. See --help.
set -euo pipefail
# The whole script is one block, read before it runs: editing the file
# while a run is under way cannot change what this run executes.
{

usage() {
  cat <<'USAGE'
Usage: deploy/reproduce.sh [options] [-- deploy/local.sh options]

Reproduces the paper's comparison: trains each method with each seed for the
same number of environment steps (deploy/local.sh), scores every kept
checkpoint of a run on the validation rooms (FloorPlan221-225; the learner
scores each in the background while it trains, the rest are scored after)
and only the best on the test rooms (FloorPlan226-230), scores the floors (an untrained
U-Net per seed; predicting everything positive), draws the training curves
and writes the results page (actor results).

Rerun the same command to continue: finished runs are skipped, a run that
was interrupted resumes from its newest checkpoint, evaluated runs are not
evaluated again. Ctrl-C (or SIGTERM) stops the current run cleanly.

Options:
  --methods LIST    comma-separated: ours, nomap-seg, nomap-noseg, intexp, and
                    ours-paper-labels / nomap-seg-paper-labels (the method
                    under the paper's label rule: background_negative = false)
                    (default: ours,nomap-seg,nomap-noseg,intexp,ours-paper-labels)
  --seeds LIST      comma-separated seeds of every method (default 0,1,2)
  --steps N         environment steps of every run (default 60000)
  --root DIR        where the runs, evaluations and manifest live
                    (default runs/reproduce)
  --checkpoints K   checkpoints spread over each run for validation to choose
                    from (default 6; plus the final one)
  --confidence-fraction F
                    confidence labels start after this fraction of --steps
                    (0.4: the paper's 400 k of about 1 M steps), or off
                    (default: off; while the network over-calls they cost
                    the ranking, docs/ladder.md)
  --views-per-scene N      test views per room, Table 1 (default 120)
  --val-views-per-scene N  validation views per room (default 120)
  --views-seed N    seed of the test and validation views (default 0)
  --renderer R      gpu or cpu, for training and evaluation (default cpu)
  --data DIR        shared data (default ../shared/data)
  --report FILE     the results page (default docs/results.md); the curves
                    go beside it as results-curves.svg
  --bin-dir DIR     use the learner and actor binaries in DIR; build nothing
  -h, --help        this help
Everything after `--` goes to every run's deploy/local.sh (default:
--actors 2 --image-size 64 --episode-steps 100, the 2-core budget). Settings
that the comparison itself decides (--method, --seed, --max-steps, --run-dir,
--resume, --scenes, --renderer, --data) are refused there.
USAGE
}

ARGS="$*"
METHODS=ours,nomap-seg,nomap-noseg,intexp,ours-paper-labels SEEDS=0,1,2 STEPS=60000
ROOT=runs/reproduce CHECKPOINTS=6 CONFIDENCE_FRACTION=off VIEWS=120 VAL_VIEWS=120
VIEWS_SEED=0 RENDERER=cpu DATA=../shared/data REPORT=docs/results.md BIN=""
LOCAL_OPTIONS=(--actors 2 --image-size 64 --episode-steps 100)
while [[ $# -gt 0 ]]; do
  case "$1" in
    --methods) METHODS="${2:?--methods needs a list}"; shift 2 ;;
    --seeds) SEEDS="${2:?--seeds needs a list}"; shift 2 ;;
    --steps) STEPS="${2:?--steps needs a number}"; shift 2 ;;
    --root) ROOT="${2:?--root needs a directory}"; shift 2 ;;
    --checkpoints) CHECKPOINTS="${2:?--checkpoints needs a number}"; shift 2 ;;
    --confidence-fraction) CONFIDENCE_FRACTION="${2:?--confidence-fraction needs a number}"; shift 2 ;;
    --views-per-scene) VIEWS="${2:?--views-per-scene needs a number}"; shift 2 ;;
    --val-views-per-scene) VAL_VIEWS="${2:?--val-views-per-scene needs a number}"; shift 2 ;;
    --views-seed) VIEWS_SEED="${2:?--views-seed needs a number}"; shift 2 ;;
    --renderer) RENDERER="${2:?--renderer needs a value}"; shift 2 ;;
    --data) DATA="${2:?--data needs a directory}"; shift 2 ;;
    --report) REPORT="${2:?--report needs a file}"; shift 2 ;;
    --bin-dir) BIN="$(cd "${2:?--bin-dir needs a directory}" && pwd)"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; LOCAL_OPTIONS=("$@"); break ;;
    *) echo "reproduce.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done

fail() { echo "reproduce.sh: $*" >&2; exit 2; }
for n in STEPS CHECKPOINTS VIEWS VAL_VIEWS; do
  [[ "${!n}" =~ ^[1-9][0-9]*$ ]] || fail "--$(tr 'A-Z_' 'a-z-' <<<"$n") needs a positive integer, got '${!n}'"
done
[[ "$VIEWS_SEED" =~ ^[0-9]+$ ]] || fail "--views-seed needs a non-negative integer, got '$VIEWS_SEED'"
[[ "$RENDERER" == cpu || "$RENDERER" == gpu ]] || fail "--renderer is cpu or gpu, got '$RENDERER'"
[[ "$CONFIDENCE_FRACTION" =~ ^(0(\.[0-9]+)?|1(\.0*)?|off)$ ]] || fail "--confidence-fraction needs a number in [0, 1] or off, got '$CONFIDENCE_FRACTION'"
IFS=, read -r -a VARIANTS <<<"$METHODS"
IFS=, read -r -a SEED_LIST <<<"$SEEDS"
[[ ${#VARIANTS[@]} -gt 0 && ${#SEED_LIST[@]} -gt 0 ]] || fail "--methods and --seeds need at least one entry each"
for v in "${VARIANTS[@]}"; do
  case "$v" in
    ours|nomap-seg|nomap-noseg|intexp|ours-paper-labels|nomap-seg-paper-labels) ;;
    *) fail "unknown method '$v' in --methods (see --help)" ;;
  esac
done
for s in "${SEED_LIST[@]}"; do [[ "$s" =~ ^[0-9]+$ ]] || fail "seeds are non-negative integers, got '$s'"; done
for o in "${LOCAL_OPTIONS[@]}"; do
  case "$o" in
    --method|--seed|--max-steps|--run-dir|--resume|--scenes|--renderer|--data)
      fail "$o is set by the comparison itself; it cannot go to local.sh here" ;;
  esac
done
[[ -d "$DATA/ithor-livingrooms" ]] || fail "no ithor-livingrooms/ under --data $DATA (the shared data directory)"
DATA=$(cd "$DATA" && pwd)

# --root and --report are relative to where the command was run.
[[ "$ROOT" == /* ]] || ROOT="$PWD/$ROOT"
[[ "$REPORT" == /* ]] || REPORT="$PWD/$REPORT"
cd "$(dirname "$0")/.."
REPO=$(pwd)
if [[ -z "$BIN" ]]; then
  command -v cargo >/dev/null || fail "cargo not found: install Rust from https://rustup.rs, or pass --bin-dir"
  echo "building release binaries..."
  cargo build --release -p learner -p actor
  TARGET_DIR=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
  BIN="$TARGET_DIR/release"
fi
for b in learner actor; do [[ -x "$BIN/$b" ]] || fail "no executable $BIN/$b"; done
source deploy/libtorch-path.sh
use_libtorch_of_python "$BIN/actor" || exit 1

mkdir -p "$ROOT"
ROOT=$(cd "$ROOT" && pwd)
if [[ "$CONFIDENCE_FRACTION" == off ]]; then
  CONFIDENCE_STEPS=9223372036854775807 # never: the largest step TOML can write
else
  CONFIDENCE_STEPS=$(python3 -c "print(int(round($STEPS * $CONFIDENCE_FRACTION)))")
fi
BATCH_STEPS=$("$BIN/learner" print-config | sed -n 's/^batch_steps = \([0-9]*\)$/\1/p')
[[ -n "$BATCH_STEPS" ]] || fail "could not read [policy] batch_steps from 'learner print-config'"
# A checkpoint every STEPS / CHECKPOINTS environment steps (PPO updates of BATCH_STEPS each).
EVERY_UPDATES=$(( (STEPS + CHECKPOINTS * BATCH_STEPS - 1) / (CHECKPOINTS * BATCH_STEPS) ))
COMMIT=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
[[ -z "$(git status --porcelain --untracked-files=no 2>/dev/null)" ]] || COMMIT="$COMMIT (with local changes)"
MACHINE="$(nproc) cores of $(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1), $(free -g | awk '/^Mem:/ {print $2}') GiB"

# The manifest records what the comparison is; a rerun must ask for the same.
MANIFEST="$ROOT/reproduce.json"
WANTED=$(python3 - "$METHODS" "$SEEDS" "$STEPS" "$CONFIDENCE_STEPS" "$VIEWS_SEED" "$VIEWS" "$VAL_VIEWS" "${LOCAL_OPTIONS[*]} --renderer $RENDERER" <<'PY'
import json, sys
m, s, steps, conf, vseed, views, vviews, local = sys.argv[1:]
print(json.dumps({"variants": m.split(","), "seeds": [int(x) for x in s.split(",")],
                  "steps": int(steps), "confidence_after_steps": int(conf),
                  "views_seed": int(vseed), "views_per_scene": int(views),
                  "val_views_per_scene": int(vviews), "local_options": local}, sort_keys=True))
PY
)
if [[ -f "$MANIFEST" ]]; then
  HAVE=$(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); k=json.loads(sys.argv[2]).keys(); print(json.dumps({x: d.get(x) for x in k}, sort_keys=True))' "$MANIFEST" "$WANTED")
  [[ "$HAVE" == "$WANTED" ]] || fail "$ROOT holds a comparison with other settings:
  it has:  $HAVE
  wanted:  $WANTED
use another --root, or the same options"
else
  python3 - "$WANTED" "$MANIFEST" "$MACHINE" "$COMMIT" <<'PY'
import json, sys, datetime
wanted, path, machine, commit = sys.argv[1:]
d = json.loads(wanted)
d.update(command="", machine=machine, commit=commit,
         started=datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"))
json.dump(d, open(path, "w"), indent=2)
PY
fi
# The page quotes the latest command (any command that gets here asked for the same settings).
python3 - "$MANIFEST" "deploy/reproduce.sh $ARGS" <<'PY'
import json, sys
path, command = sys.argv[1:]
d = json.load(open(path)); d["command"] = command; json.dump(d, open(path, "w"), indent=2)
PY

# One learner config per variant: the confidence step, checkpoint spacing, labels.
mkdir -p "$ROOT/configs"
variant_method() { echo "${1%-paper-labels}"; }
variant_config() {
  local v=$1 file="$ROOT/configs/$1.toml"
  {
    echo "# Written by deploy/reproduce.sh for variant $v."
    echo "checkpoint_every_updates = $EVERY_UPDATES"
    echo "checkpoint_interval_s = 900.0"
    echo "keep_checkpoints = $((CHECKPOINTS * 3 + 2))"
    echo
    echo "[task]"
    echo "confidence_after_steps = $CONFIDENCE_STEPS"
    if [[ "$v" == *-paper-labels ]]; then echo "background_negative = false"; fi
  } >"$file"
  echo "$file"
}

# Seed by seed, so that an unfinished comparison has every method at its first seeds.
RUNS=()
for s in "${SEED_LIST[@]}"; do for v in "${VARIANTS[@]}"; do RUNS+=("$v:$s"); done; done
TOTAL=${#RUNS[@]}
CURRENT_PID=""
on_signal() {
  trap - INT TERM
  echo; echo "reproduce.sh: stopping (rerun the same command to continue)"
  [[ -n "$CURRENT_PID" ]] && kill -TERM "$CURRENT_PID" 2>/dev/null && wait "$CURRENT_PID" 2>/dev/null
  exit 130
}
trap on_signal INT TERM

newest_checkpoint() {
  { ls "$1/checkpoints" 2>/dev/null || true; } | { grep -E '^[0-9]+$' || true; } | sort -n | tail -n 1
}

# Steps still to train in the runs other than $1, for the overall ETA.
remaining_steps_besides() {
  local total=0 v s dir done_steps
  for run in "${RUNS[@]}"; do
    v=${run%%:*} s=${run##*:} dir="$ROOT/$v-seed$s"
    [[ -e "$dir/trained" || "$dir" == "$1" ]] && continue
    done_steps=$(newest_checkpoint "$dir"); done_steps=${done_steps:-0}
    total=$((total + (STEPS > done_steps ? STEPS - done_steps : 0)))
  done
  echo "$total"
}

fmt_duration() { printf '%dh%02dm' $(($1 / 3600)) $(($1 % 3600 / 60)); }

train() {
  local index=$1 v=$2 s=$3 dir="$ROOT/$2-seed$3" args learner_args
  local method; method=$(variant_method "$v")
  if [[ -e "$dir/trained" ]]; then
    echo "[$index/$TOTAL] $v seed $s: trained"; return 0
  fi
  if [[ -n "$(newest_checkpoint "$dir")" ]]; then
    echo "[$index/$TOTAL] $v seed $s: resuming from step $(newest_checkpoint "$dir")"
    # A resumed run keeps the settings saved in its config.toml.
    args=(--run-dir "$dir" --resume) learner_args=()
  else
    if [[ -e "$dir" ]]; then
      local aside="$ROOT/abandoned/$v-seed$s-$(date -u +%Y%m%dT%H%M%SZ)"
      mkdir -p "$ROOT/abandoned"; mv "$dir" "$aside"
      echo "[$index/$TOTAL] $v seed $s: an earlier start left no checkpoint; moved it to $aside"
    fi
    echo "[$index/$TOTAL] $v seed $s: training $STEPS steps"
    args=(--run-dir "$dir" --method "$method" --seed "$s")
    # The learner scores each checkpoint on the validation views in the
    # background; the evaluation below chooses from those scores.
    learner_args=(-- --config "$(variant_config "$v")" --set "validation.views_per_room=$VAL_VIEWS"
      --set "validation.seed=$VIEWS_SEED")
  fi
  mkdir -p "$dir/logs"
  "$REPO/deploy/local.sh" "${args[@]}" --max-steps "$STEPS" --renderer "$RENDERER" --data "$DATA" \
    --bin-dir "$BIN" "${LOCAL_OPTIONS[@]}" "${learner_args[@]}" \
    >>"$dir/logs/local.log" 2>&1 &
  CURRENT_PID=$!
  local start_s=$SECONDS start_steps="" steps rate eta_run eta_all left
  while kill -0 "$CURRENT_PID" 2>/dev/null; do
    sleep 30 & wait $! || true
    [[ -s "$dir/http.addr" ]] || continue
    steps=$(curl -fsS --max-time 5 "http://$(cat "$dir/http.addr")/api/status" 2>/dev/null \
      | grep -o '"env_steps":[0-9]*' | head -n 1 | cut -d: -f2 || true)
    [[ -n "$steps" ]] || continue
    [[ -n "$start_steps" ]] || { start_steps=$steps; start_s=$SECONDS; continue; }
    rate=$(( (steps - start_steps) / (SECONDS - start_s > 0 ? SECONDS - start_s : 1) ))
    if [[ $rate -gt 0 ]]; then
      left=$(( STEPS > steps ? STEPS - steps : 0 ))
      eta_run=$(fmt_duration $((left / rate)))
      eta_all=$(fmt_duration $(( (left + $(remaining_steps_besides "$dir")) / rate )))
    else
      eta_run="?" eta_all="?"
    fi
    echo "[$index/$TOTAL] $v seed $s: $steps / $STEPS steps, $rate steps/s, this run $eta_run, all training ~$eta_all"
  done
  local code=0; wait "$CURRENT_PID" || code=$?
  CURRENT_PID=""
  local reached; reached=$(newest_checkpoint "$dir"); reached=${reached:-0}
  if [[ $reached -ge $STEPS ]]; then
    touch "$dir/trained"
    echo "[$index/$TOTAL] $v seed $s: trained ($reached steps, final checkpoint)"
  else
    echo "reproduce.sh: $v seed $s stopped at checkpoint $reached of $STEPS steps (local.sh status $code); see $dir/logs/" >&2
    tail -n 5 "$dir/logs/local.log" >&2
    echo "rerun the same command to resume it" >&2
    exit 1
  fi
}

evaluate_run() {
  local index=$1 v=$2 s=$3 dir="$ROOT/$2-seed$3"
  [[ -s "$dir/eval/test.json" ]] && { echo "[$index/$TOTAL] $v seed $s: evaluated"; return 0; }
  mkdir -p "$dir/eval"
  echo "[$index/$TOTAL] $v seed $s: choosing a checkpoint on the validation rooms, then the test rooms"
  "$BIN/actor" evaluate --run-dir "$dir" --select --views-per-scene "$VIEWS" \
    --val-views-per-scene "$VAL_VIEWS" --seed "$VIEWS_SEED" --renderer "$RENDERER" --data "$DATA" \
    --json "$dir/eval/test.json.partial" >"$dir/eval/test.md" 2>"$dir/eval/evaluate.log" \
    || { echo "reproduce.sh: evaluating $dir failed; see $dir/eval/evaluate.log" >&2; tail -n 5 "$dir/eval/evaluate.log" >&2; exit 1; }
  mv "$dir/eval/test.json.partial" "$dir/eval/test.json"
  sed -n 's/^Checkpoint chosen/  checkpoint chosen/p' "$dir/eval/test.md" | cut -c1-240
}

index=0
for run in "${RUNS[@]}"; do
  index=$((index + 1))
  train "$index" "${run%%:*}" "${run##*:}"
  evaluate_run "$index" "${run%%:*}" "${run##*:}"
done

# Floors: an untrained U-Net per seed, on the same test views.
FIRST="$ROOT/${VARIANTS[0]}-seed${SEED_LIST[0]}"
mkdir -p "$ROOT/floors"
for s in "${SEED_LIST[@]}"; do
  out="$ROOT/floors/untrained-seed$s.json"
  [[ -s "$out" ]] && continue
  echo "floor: the untrained U-Net of seed $s"
  "$BIN/actor" evaluate --run-dir "$FIRST" --untrained "$s" --views-per-scene "$VIEWS" \
    --seed "$VIEWS_SEED" --renderer "$RENDERER" --data "$DATA" --json "$out.partial" \
    >"$ROOT/floors/untrained-seed$s.md" 2>"$ROOT/floors/untrained-seed$s.log"
  mv "$out.partial" "$out"
done

# Curves: each variant's seeds as a band.
PLOT_ARGS=()
for v in "${VARIANTS[@]}"; do
  dirs=()
  for s in "${SEED_LIST[@]}"; do dirs+=("$ROOT/$v-seed$s"); done
  PLOT_ARGS+=(--run-dir "$v=$(IFS=,; echo "${dirs[*]}")")
done
REPORT_DIR=$(dirname "$REPORT")
mkdir -p "$REPORT_DIR"
CURVES="$REPORT_DIR/results-curves.svg"
"$BIN/learner" plot "${PLOT_ARGS[@]}" --out "$CURVES"
"$BIN/actor" results --root "$ROOT" --out "$REPORT" --curves "$(basename "$CURVES")"
echo "done: $REPORT (curves: $CURVES)"
exit
}
