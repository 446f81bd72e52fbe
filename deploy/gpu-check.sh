#!/usr/bin/env bash
# The checks to run first whenever a GPU machine is lent: agreement, training
# speed beside PyTorch, learner capacity, whole-system throughput. One
# Markdown report. See `deploy/gpu-check.sh --help`.
set -uo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/gpu-check.sh --bin-dir DIR [options]

Runs, one after the other, each under a time limit (about 9 minutes in all):
  1. the CPU/GPU agreement test (DIR/gpu_matches_cpu, TF32 off);
  2. the training benchmark beside PyTorch on the same GPU (DIR/learning with
     AFX_BENCH_ONLY=gpu-check: PPO update of 1024 steps at 64 and 128 px, U-Net
     training step; needs python3 with torch for the PyTorch column), then one
     U-Net inference call per batch size beside PyTorch's (DIR/unet_inference,
     when DIR has it, and learner/training/benches/torch_unet_inference.py),
     and one step of the trainers' Adam against burn's (DIR/adam_steps);
  3. the learner's capacity with synthetic actors (`learner bench-capacity`)
     at 64 px (100-step episodes; PPO batches of 128 and 1024 steps) and
     128 px (600-step episodes, 1024-step batches), then what gathering and
     building a 1024-step PPO batch costs on libtorch (DIR/ppo_batches, when
     DIR has it);
  4. one actor process's environments at 128 px with the GPU renderer
     (DIR/env_steps, its several-environments table for 1 and 32
     environments, 600-step episodes), when DIR has env_steps; with the CPU
     renderer where the machine has no Vulkan adapter for the GPU one;
  5. deploy/throughput.sh: the whole system, `ours`, 1x32 at 64 px with the CPU
     renderer, and 1x32 at 128 px with the GPU renderer (when Vulkan works)
     and with the CPU renderer, then the last again with the actors never
     held for the U-Net trainer (decision 0013's hold off: what the actors
     make, and the frames the trainer skips), PPO on 1024-step batches
     (what docs/running.md advises on a GPU), with the CPU cores the learner and the actors kept busy (and per thread
     name), the messages lost by kind, each actor's loop thread's chores per
     step, its U-Net batching threads' share and its environments' steps;
  6. the gateway pair against loopback TCP (`gateway bench`, issue 41's
     figure, which the 2-core VM cannot reach), when DIR has gateway.
and writes every result into one Markdown report.

DIR holds the binaries built here with a GPU backend, FEATURE being nets/gpu
(burn's wgpu backend) or nets/gpu-torch (libtorch on CUDA; needs LIBTORCH at
build time, see docs/decisions/0010-libtorch-on-a-gpu.md), and TRAINING the
same with training/gpu-torch added for libtorch (the trainers' own steps):
  cargo build --release -p learner -p actor --features TRAINING
  cargo build --release -p training --bench learning --bench adam_steps --features TRAINING
  cargo build --release -p nets --test gpu_matches_cpu --features FEATURE
  cargo build --release -p actor --bench env_steps --features FEATURE
  cargo build --release -p nets --bench unet_inference --features FEATURE
  cargo build --release -p learner --bench ppo_batches --features TRAINING
  cargo build --release -p gateway
(copy target/release/{learner,actor,gateway} and the deps/learning-*, deps/gpu_matches_cpu-*,
deps/env_steps-*, deps/unet_inference-*, deps/adam_steps-*, deps/ppo_batches-* executables
into DIR by their names without the hash; deploy/build-gpu-torch.sh --checks does all of
this for libtorch). Binaries linked to
libtorch find it through LD_LIBRARY_PATH, which this script points at the
libtorch of python3's torch when the loader cannot find it otherwise.

Options:
  --bin-dir DIR   the binaries (required)
  --data DIR      shared data for the actors (default ../shared/data)
  --out FILE      the report (default gpu-check.md)
  --logs DIR      full logs of every step (default gpu-check-logs)
  --skip LIST     comma-separated steps to leave out: agreement, training,
                  capacity, actor, throughput, gateway
  --quick         shorter windows (a smoke test of the script itself)
  -h, --help      this help
USAGE
}

BIN="" DATA="" OUT_FILE="gpu-check.md" LOGS="gpu-check-logs" SKIP="" QUICK=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --bin-dir) BIN="${2:?--bin-dir needs a directory}"; shift 2 ;;
    --data) DATA="${2:?--data needs a directory}"; shift 2 ;;
    --out) OUT_FILE="${2:?--out needs a file}"; shift 2 ;;
    --logs) LOGS="${2:?--logs needs a directory}"; shift 2 ;;
    --skip) SKIP="${2:?--skip needs a list}"; shift 2 ;;
    --quick) QUICK=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "gpu-check.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ -n "$BIN" ]] || { echo "gpu-check.sh: --bin-dir is required" >&2; usage >&2; exit 2; }
BIN="$(cd "$BIN" 2>/dev/null && pwd)" || { echo "gpu-check.sh: no directory $BIN" >&2; exit 2; }
REPO="$(cd "$(dirname "$0")/.." && pwd)"
[[ -n "$DATA" ]] || DATA="$REPO/../shared/data"
mkdir -p "$LOGS"
LOGS="$(cd "$LOGS" && pwd)"
skipped() { [[ ",$SKIP," == *",$1,"* ]]; }

# A libtorch build finds libtorch through python3's torch if need be.
source "$REPO/deploy/libtorch-path.sh"
use_libtorch_of_python "$BIN/learner" || exit 2

if [[ $QUICK -eq 1 ]]; then
  CAP_WARMUP=5 CAP_SECONDS=10 TP_WARMUP=15 TP_SECONDS=15 BENCH_QUICK=1
else
  CAP_WARMUP=10 CAP_SECONDS=20 TP_WARMUP=20 TP_SECONDS=25 BENCH_QUICK=
fi

# The report grows line by line, so a run stopped early keeps what it measured.
: >"$OUT_FILE"
add() { printf '%s\n' "$@" >>"$OUT_FILE"; }
section() { printf '\n=== %s (%(%H:%M:%S)T)\n' "$1" -1 >&2; add "" "## $1" ""; }
# Runs a step under a time limit, its output into LOG; says how it ended.
limited() { # seconds log command...
  local limit=$1 log=$2; shift 2
  timeout --signal=TERM --kill-after=15 "$limit" "$@" >"$log" 2>&1
  local rc=$?
  [[ $rc -eq 124 ]] && echo "(stopped at its ${limit} s limit)" >>"$log"
  return $rc
}

add "# GPU check" "" \
  "$(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO" rev-parse --short HEAD 2>/dev/null || echo unknown)" \
  "" "GPU: $(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || echo 'nvidia-smi not found')" \
  "CPU: $(nproc) cores"

if ! skipped agreement; then
  section "CPU/GPU agreement (gpu_matches_cpu)"
  # Without TF32 (cuDNN's default on libtorch): the test compares arithmetic,
  # not precision modes (nets/tests/gpu_matches_cpu.rs).
  if ! NVIDIA_TF32_OVERRIDE=0 limited 120 "$LOGS/agreement.log" "$BIN/gpu_matches_cpu" --test-threads 1 --nocapture; then
    add "FAILED:" '```' "$(tail -n 15 "$LOGS/agreement.log")" '```'
  elif grep -q '^skipping' "$LOGS/agreement.log"; then
    add "NOT RUN (no usable GPU): $(grep -m1 '^skipping' "$LOGS/agreement.log")"
  else
    add "passed: $(grep -E '^test result' "$LOGS/agreement.log" | tail -1)" "" \
      "$(grep -E '^max|^after one step' "$LOGS/agreement.log")"
  fi
fi

if ! skipped training; then
  section "Training steps beside PyTorch (same GPU)"
  AFX_DEVICE=gpu AFX_BENCH_ONLY=gpu-check AFX_BENCH_QUICK=$BENCH_QUICK \
    AFX_TORCH_REFERENCE="$REPO/learner/training/benches/torch_reference.py" \
    limited 150 "$LOGS/training.log" "$BIN/learning"
  add '```' "$(grep -vE '^\s*$' "$LOGS/training.log" | grep -E 'burn|pytorch|median|ours /|skipped|stopped|error|panic' | tail -n 20)" '```'
  if [[ -x "$BIN/unet_inference" ]]; then
    add "" "One U-Net inference call at 128 px (an actor's batching thread's), ours then PyTorch's:" ""
    AFX_DEVICE=gpu limited 60 "$LOGS/unet-inference.log" "$BIN/unet_inference"
    add "$(grep -E '^\|' "$LOGS/unet-inference.log" || echo "FAILED: $(tail -n 3 "$LOGS/unet-inference.log" | tr '\n' ' ')")" ""
    limited 90 "$LOGS/torch-unet-inference.log" python3 "$REPO/learner/training/benches/torch_unet_inference.py" --device cuda --quick
    add "$(grep -E '^\|' "$LOGS/torch-unet-inference.log" || echo "PyTorch's: not run: $(tail -n 1 "$LOGS/torch-unet-inference.log")")"
  fi
  if [[ -x "$BIN/adam_steps" ]]; then
    add "" "One Adam step, the trainers' (training::adam) against burn's (adam_steps):" ""
    AFX_DEVICE=gpu AFX_REPEATS=30 limited 60 "$LOGS/adam-steps.log" "$BIN/adam_steps"
    add "$(grep -E '^\|' "$LOGS/adam-steps.log" || echo "FAILED: $(tail -n 3 "$LOGS/adam-steps.log" | tr '\n' ' ')")"
  fi
fi

if ! skipped capacity; then
  section "Learner capacity, synthetic actors (learner bench-capacity)"
  header_done=0
  # The learner's default PPO batch, and the 1024 steps a GPU wants (docs/running.md).
  for setting in "64 100 4 128" "64 100 4 1024" "128 600 4 1024"; do
    read -r side steps feeds batch <<<"$setting"
    log="$LOGS/capacity-${side}px-${batch}.log"
    limited $((CAP_WARMUP + CAP_SECONDS + 90)) "$log" "$BIN/learner" bench-capacity --device gpu \
      --image-size "$side" --episode-steps "$steps" --actors "$feeds" --batch-steps "$batch" \
      --warmup "$CAP_WARMUP" --seconds "$CAP_SECONDS"
    if grep -q '^| setting' "$log"; then
      [[ $header_done -eq 1 ]] || add "$(grep -A1 '^| setting' "$log")"
      header_done=1
      add "$(grep -A2 '^| setting' "$log" | tail -n 1)"
    else
      add "${side} px, ${batch}-step batches: FAILED: $(tail -n 3 "$log" | tr '\n' ' ')"
    fi
  done
  if [[ -x "$BIN/ppo_batches" ]]; then
    add "" "A PPO batch of 1 024 steps gathered and built on libtorch (the learner's ppo-batching thread; ppo_batches):" ""
    AFX_DEVICE=gpu AFX_REPEATS=3 limited 90 "$LOGS/ppo-batches.log" "$BIN/ppo_batches"
    add "$(grep -E '^\|' "$LOGS/ppo-batches.log" || echo "FAILED: $(tail -n 3 "$LOGS/ppo-batches.log" | tr '\n' ' ')")" ""
  fi
fi

NO_VULKAN=0
if ! skipped actor && [[ -x "$BIN/env_steps" ]]; then
  section "One actor process at 128 px, GPU renderer (env_steps)"
  # 32 environments as the actor runs them (each on its own thread, the
  # U-Net's frames in a batching thread's batches; at 128 px more
  # environments than cores pay), 1 for scale; the paper's 600-step episodes, over which the
  # map fills the room and its and the state's cost per step grows (3.3x
  # and 2.1x from 60 steps, docs/notebook/2026-11-27-actor-loop-chores.md).
  actor_table() { # renderer
    AFX_DEVICE=gpu AFX_DATA="$DATA" AFX_CASES=none AFX_ENVS=1,32 AFX_STEPS=600 AFX_ENVS_PX=128 AFX_ENVS_RENDERER="$1" \
      limited 240 "$LOGS/actor-$1.log" "$BIN/env_steps"
  }
  actor_table gpu
  log="$LOGS/actor-gpu.log"
  if grep -q 'NoAdapter' "$log"; then
    # The GPU renderer needs the driver's Vulkan, which some machines lack
    # (seen on an H200 whose ICD gave no vkCreateInstance, 2026-12-01).
    NO_VULKAN=1
    add "No Vulkan adapter for the GPU renderer ($(grep -m1 -o 'NoAdapter.*' "$log" | cut -c1-120)); measured with the CPU renderer instead:" ""
    actor_table cpu
    log="$LOGS/actor-cpu.log"
  fi
  add "$(grep -E '^\||^Several' "$log" || echo "FAILED: $(tail -n 5 "$log" | tr '\n' ' ')")"
fi

if ! skipped throughput; then
  section "Whole system, ours (deploy/throughput.sh)"
  # 64 px with the CPU renderer (bound by the CPU: 85-90 % busy); 128 px on
  # both renderers: at f489cff the machine was 36-43 % idle there, and the
  # GPU renderer's Vulkan work may wait for its turn on a GPU the learner's
  # and the actor's CUDA contexts share (MPS cannot merge a Vulkan context),
  # which the CPU renderer, at a cost in CPU, would not. One process of 32
  # (2x16 was no faster).
  # The last setting without the hold (actors wait while the U-Net trainer
  # owes more than 8 episodes' steps, decision 0013): what the actors make
  # when they need not wait, and how many frames the trainer then skips.
  for setting in "1x32 64 100 cpu hold" "1x32 128 600 gpu hold" "1x32 128 600 cpu hold" "1x32 128 600 cpu nohold"; do
    read -r pairs side steps renderer hold <<<"$setting"
    if [[ $renderer == gpu && $NO_VULKAN -eq 1 ]]; then
      add "${side} px, ${steps}-step episodes, gpu renderer: not run (no Vulkan adapter, above)" ""
      continue
    fi
    name="${side}px-${renderer}"; hold_set=()
    [[ $hold == hold ]] || { name+="-nohold"; hold_set=(--set unet.hold_actors_beyond_episodes=0); }
    log="$LOGS/throughput-${name}.log"
    n=$(tr ',' '\n' <<<"$pairs" | wc -l)
    limited $(( n * (TP_WARMUP + TP_SECONDS + 60) )) "$log" "$REPO/deploy/throughput.sh" \
      --settings "$pairs" --warmup "$TP_WARMUP" --seconds "$TP_SECONDS" \
      --runs-dir "$LOGS/runs-${name}" -- --bin-dir "$BIN" --device gpu --data "$DATA" \
      --image-size "$side" --episode-steps "$steps" --renderer "$renderer" \
      -- --set policy.batch_steps=1024 "${hold_set[@]}"
    add "${side} px, ${steps}-step episodes, ${renderer} renderer, 1024-step PPO batches$([[ $hold == hold ]] || echo ', actors never held for the U-Net'):" ""
    if grep -q '^| actors' "$log"; then
      add "$(sed -n '/^| actors/,$p' "$log")" ""
      # Whether each actor's loop thread or U-Net batching threads (which
      # all its environments wait for) were the wall: its last lines say
      # how busy they were, and what its environments' steps were made of.
      for run in "$LOGS/runs-${name}"/*/; do
        busy=$(grep -hE "loop's thread was busy|U-Net batches of|environments' steps took" "$run"logs/actor-*.log 2>/dev/null)
        [[ -z "$busy" ]] || add "$(basename "$run"), the actors' loops, U-Net batches and steps:" "" "$busy" ""
      done
    else
      add "FAILED: $(tail -n 5 "$log" | tr '\n' ' ')" ""
    fi
  done
fi

if ! skipped gateway && [[ -x "$BIN/gateway" ]]; then
  section "Gateway pair against loopback TCP (gateway bench)"
  limited 150 "$LOGS/gateway.log" "$BIN/gateway" bench --sizes-mib 0.1,1,4,16 --count 30
  add "$(grep -E '^\|' "$LOGS/gateway.log" || echo "FAILED: $(tail -n 5 "$LOGS/gateway.log" | tr '\n' ' ')")"
fi

cat "$OUT_FILE"
echo "report: $OUT_FILE; logs: $LOGS" >&2
