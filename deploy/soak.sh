#!/usr/bin/env bash
# Runs deploy/local.sh for a fixed time, samples the memory of the learner and
# of every actor, optionally SIGKILLs actors as a drill, stops the run cleanly
# and says whether memory stayed flat. See `deploy/soak.sh --help`.
set -euo pipefail
{

usage() {
  cat <<'USAGE'
Usage: deploy/soak.sh --run-dir DIR [options] -- <deploy/local.sh options>

Starts `deploy/local.sh --run-dir DIR <options>` (in its own process group),
samples the resident memory (RSS, from /proc) of the learner and of every actor
every --every seconds into DIR/soak.csv, and after --minutes stops the run as
Ctrl-C would (final checkpoint). Then it writes DIR/soak.md: per process, the
median RSS of the --window minutes after --warmup and of the last --window minutes,
their ratio, the largest sample and how many processes held the role (an actor
restarted by the supervisor counts again); and after the stop, whether every kept
checkpoint verifies against its manifest (sha256sum, not the learner's code) and
whether the run left anything in /dev/shm. Exit status 2 when a ratio is outside
1 ± --tolerance (memory did not stay flat), 3 when a checkpoint does not verify or
shared memory was left, 0 otherwise.

Options:
  --run-dir DIR     the run directory (passed to local.sh; required); one that
                    already holds checkpoints is continued with --resume
  --minutes M       how long the run goes (default 60)
  --every S         seconds between samples (default 30)
  --warmup M        minutes left out before the baseline (default 10: networks,
                    pools and the U-Net's dataset fill first)
  --window M        minutes of the baseline and of the end (default 5)
  --tolerance F     allowed relative change of the median RSS (default 0.10)
  --kill-every S    SIGKILL a random actor every S seconds (a kill drill;
                    default 0 = never); the supervisor restarts it
  --kill-learner-every S
                    SIGKILL the learner every S seconds (default 0 = never),
                    then start the run again with `local.sh --resume`, as a
                    user would; the run continues from its newest checkpoint
  -h, --help        this help
Everything after `--` goes to deploy/local.sh, e.g.
  deploy/soak.sh --run-dir runs/soak -- --actors 8 --image-size 64 --episode-steps 100 --renderer cpu
USAGE
}

RUN_DIR="" MINUTES=60 EVERY=30 WARMUP=10 WINDOW=5 TOLERANCE=0.10 KILL_EVERY=0 KILL_LEARNER_EVERY=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --run-dir) RUN_DIR="${2:?--run-dir needs a directory}"; shift 2 ;;
    --minutes) MINUTES="${2:?--minutes needs a number}"; shift 2 ;;
    --every) EVERY="${2:?--every needs seconds}"; shift 2 ;;
    --warmup) WARMUP="${2:?--warmup needs minutes}"; shift 2 ;;
    --window) WINDOW="${2:?--window needs minutes}"; shift 2 ;;
    --tolerance) TOLERANCE="${2:?--tolerance needs a fraction}"; shift 2 ;;
    --kill-every) KILL_EVERY="${2:?--kill-every needs seconds}"; shift 2 ;;
    --kill-learner-every) KILL_LEARNER_EVERY="${2:?--kill-learner-every needs seconds}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; break ;;
    *) echo "soak.sh: unknown option $1 (options for local.sh go after --; see --help)" >&2; exit 64 ;;
  esac
done
[[ -n "$RUN_DIR" ]] || { echo "soak.sh: --run-dir is required (see --help)" >&2; exit 64; }
for number in "$MINUTES" "$EVERY" "$WARMUP" "$WINDOW" "$KILL_EVERY" "$KILL_LEARNER_EVERY"; do
  [[ "$number" =~ ^[0-9]+$ ]] || { echo "soak.sh: '$number' is not a whole number (see --help)" >&2; exit 64; }
done
[[ "$EVERY" -ge 1 ]] || { echo "soak.sh: --every must be at least 1" >&2; exit 64; }
command -v python3 >/dev/null || { echo "soak.sh: python3 is needed for the summary" >&2; exit 69; }

HERE="$(cd "$(dirname "$0")" && pwd)"
mkdir -p "$RUN_DIR"
LOGS="$RUN_DIR/logs"
CSV="$RUN_DIR/soak.csv"
echo "elapsed_s,role,pid,rss_kib" >"$CSV"
shm_files() { ls /dev/shm 2>/dev/null | grep '^iox2_' | sort || true; }
SHM_BEFORE="$(shm_files)"
RESUME=()
[[ -d "$RUN_DIR/checkpoints" ]] && RESUME=(--resume)
start_run() {
  setsid "$HERE/local.sh" --run-dir "$RUN_DIR" "${RESUME[@]}" "$@" >>"$RUN_DIR/soak-local.log" 2>&1 &
  LOCAL_PID=$!
}
: >"$RUN_DIR/soak-local.log"
start_run "$@"
stop_run() {
  kill -TERM "$LOCAL_PID" 2>/dev/null || true
  wait "$LOCAL_PID" 2>/dev/null || true
}
trap 'echo "soak.sh: interrupted, stopping the run"; stop_run; exit 130' INT TERM

for _ in $(seq 1 600); do
  [[ -s "$LOGS/learner.pid" ]] && break
  kill -0 "$LOCAL_PID" 2>/dev/null || { echo "soak.sh: local.sh exited at start; see $RUN_DIR/soak-local.log" >&2; tail -n 20 "$RUN_DIR/soak-local.log" >&2; exit 1; }
  sleep 1
done
[[ -s "$LOGS/learner.pid" ]] || { echo "soak.sh: no learner after 10 minutes; see $RUN_DIR/soak-local.log" >&2; stop_run; exit 1; }

echo "soak: $MINUTES min, a sample every $EVERY s into $CSV (local.sh log: $RUN_DIR/soak-local.log)"
START=$SECONDS
NEXT_KILL=$KILL_EVERY
NEXT_LEARNER_KILL=$KILL_LEARNER_EVERY
KILLS=0 LEARNER_KILLS=0
while (( SECONDS - START < MINUTES * 60 )); do
  kill -0 "$LOCAL_PID" 2>/dev/null || { echo "soak.sh: local.sh stopped early; see $RUN_DIR/soak-local.log" >&2; break; }
  now=$((SECONDS - START))
  for pidfile in "$LOGS"/learner.pid "$LOGS"/actor-*.pid; do
    [[ -s "$pidfile" ]] || continue
    role="$(basename "$pidfile" .pid)"
    pid="$(cat "$pidfile")"
    rss="$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)"
    [[ -n "$rss" ]] && echo "$now,$role,$pid,$rss" >>"$CSV"
  done
  if (( KILL_EVERY > 0 && now >= NEXT_KILL )); then
    mapfile -t actors < <(ls "$LOGS"/actor-*.pid 2>/dev/null)
    if (( ${#actors[@]} > 0 )); then
      victim="${actors[RANDOM % ${#actors[@]}]}"
      kill -KILL "$(cat "$victim")" 2>/dev/null && KILLS=$((KILLS + 1)) \
        && echo "soak: SIGKILL $(basename "$victim" .pid) at ${now} s"
    fi
    NEXT_KILL=$((NEXT_KILL + KILL_EVERY))
  fi
  if (( KILL_LEARNER_EVERY > 0 && now >= NEXT_LEARNER_KILL )); then
    NEXT_LEARNER_KILL=$((NEXT_LEARNER_KILL + KILL_LEARNER_EVERY))
    old="$(cat "$LOGS/learner.pid" 2>/dev/null || true)"
    if [[ -n "$old" ]] && kill -KILL "$old" 2>/dev/null; then
      LEARNER_KILLS=$((LEARNER_KILLS + 1))
      echo "soak: SIGKILL learner at ${now} s; local.sh stops the actors, then --resume"
      wait "$LOCAL_PID" 2>/dev/null || true
      RESUME=(--resume)
      start_run "$@"
      for _ in $(seq 1 600); do
        new="$(cat "$LOGS/learner.pid" 2>/dev/null || true)"
        [[ -n "$new" && "$new" != "$old" ]] && break
        kill -0 "$LOCAL_PID" 2>/dev/null || break
        sleep 1
      done
      kill -0 "$LOCAL_PID" 2>/dev/null || { echo "soak.sh: the resumed run did not start; see $RUN_DIR/soak-local.log" >&2; break; }
      echo "soak: resumed ($(grep -o 'resumed from checkpoint [^ ]*' "$LOGS/learner.log" | tail -n 1))"
    fi
  fi
  if (( now % 300 < EVERY )); then
    echo "soak: $((now / 60)) of $MINUTES min; $(curl -s --max-time 5 "http://$(cat "$RUN_DIR/http.addr" 2>/dev/null)/api/status" \
      | python3 -c 'import json,sys; s=json.load(sys.stdin); print(s["env_steps"], "steps,", s["actors_alive"], "actors alive")' 2>/dev/null || echo 'status unavailable')"
  fi
  sleep "$EVERY"
done
echo "soak: stopping the run (final checkpoint)"
trap - INT TERM
stop_run
sleep 1
LEFT="$(comm -13 <(echo "$SHM_BEFORE") <(shm_files) | tr '\n' ' ')"

code=0
python3 - "$CSV" "$WARMUP" "$TOLERANCE" "$KILLS" "$WINDOW" "$MINUTES" "$LEARNER_KILLS" "$RUN_DIR" "$LEFT" >"$RUN_DIR/soak.md" <<'PY' || code=$?
import csv, hashlib, json, os, statistics, subprocess, sys
path, warmup_min, tolerance, kills = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
learner_kills, run_dir, left = int(sys.argv[7]), sys.argv[8], sys.argv[9].split()
window = float(sys.argv[5]) * 60
planned = float(sys.argv[6]) * 60
rows = list(csv.DictReader(open(path)))
if not rows:
    print("no samples"); sys.exit(1)
# The end window closes where the run was planned to stop (a run that
# stopped early has no samples there, and says so below).
end = planned
start = warmup_min * 60
last_sample = max(int(r["elapsed_s"]) for r in rows)
print(f"Soak: {last_sample / 60:.1f} of {planned / 60:g} min sampled, {len(rows)} samples, {kills} actors and {learner_kills} learners SIGKILLed; baseline = minutes {warmup_min:g}-{warmup_min + window / 60:g}, end = the last {window / 60:g} minutes.\n")
print("| process | baseline RSS (MiB) | end RSS (MiB) | end / baseline | largest (MiB) | processes |")
print("|---|---|---|---|---|---|")
flat = True
for role in sorted({r["role"] for r in rows}, key=lambda r: (r != "learner", r)):
    mine = [r for r in rows if r["role"] == role]
    mib = lambda rs: [int(r["rss_kib"]) / 1024 for r in rs]
    base = mib([r for r in mine if start <= int(r["elapsed_s"]) < start + window])
    last = mib([r for r in mine if int(r["elapsed_s"]) >= end - window])
    if not base or not last or start + window > end - window:
        print(f"| {role} | – | – | too short a run for a baseline and an end | {max(mib(mine)):.0f} | {len({r['pid'] for r in mine})} |")
        flat = False
        continue
    ratio = statistics.median(last) / statistics.median(base)
    ok = abs(ratio - 1) <= tolerance
    flat &= ok
    print(f"| {role} | {statistics.median(base):.0f} | {statistics.median(last):.0f} | {ratio:.3f}{'' if ok else ' **not flat**'} | {max(mib(mine)):.0f} | {len({r['pid'] for r in mine})} |")
print(f"\nMemory {'stayed flat' if flat else 'did NOT stay flat'} within ±{tolerance:.0%}.")
# Every kept checkpoint against its manifest, by sha256sum (an outside reader).
checkpoints = os.path.join(run_dir, "checkpoints")
steps = sorted((int(d) for d in os.listdir(checkpoints) if d.isdigit()) if os.path.isdir(checkpoints) else [])
bad = []
for step in steps:
    d = os.path.join(checkpoints, str(step))
    try:
        manifest = json.load(open(os.path.join(d, "manifest.json")))
        for f in manifest["files"]:
            out = subprocess.run(["sha256sum", os.path.join(d, f["name"])], capture_output=True, text=True)
            if out.returncode != 0 or out.stdout.split()[0] != f["sha256"]:
                bad.append(f"{step}/{f['name']}")
    except (OSError, ValueError, KeyError) as e:
        bad.append(f"{step} ({e})")
print(f"Checkpoints kept: {len(steps)} ({', '.join(map(str, steps)) or 'none'}); "
      + ("all verify against their manifests (sha256sum)." if not bad else f"NOT verifying: {', '.join(bad)}."))
print("Shared memory left in /dev/shm: " + (", ".join(left) if left else "none") + ".")
sys.exit(2 if not flat else 3 if bad or left or not steps else 0)
PY
cat "$RUN_DIR/soak.md"
exit "$code"
}
