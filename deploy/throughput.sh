#!/usr/bin/env bash
# Measures the whole system's environment steps/s (learner training beside the
# actors) for several actor × environment settings, one run after the other.
# See `deploy/throughput.sh --help`.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/throughput.sh [options] [-- local.sh options]

For each setting AxK, starts `deploy/local.sh --actors A --envs-per-actor K` on a
fresh run, lets it warm up, counts the environment steps the learner receives
over the measuring window (its /api/status), stops the run, and prints a
Markdown table: steps/s the learner took from all actors and per actor
process, PPO updates/s, labelled frames the U-Net trainer took and skipped,
rollout steps PPO discarded (it was behind), and messages lost in transit
(with their share of all messages sent in the window, and which kinds), the
share of the window the learner's receive loop was busy (not waiting; with
its passes over 0.1 s and the longest since the run began), and how many CPU
cores the learner process and the actor processes kept busy over the window
(their CPU time from /proc over its length; the cores this script may use
beside them),
which tells a run bound by the CPU from one bound by something else. A second
table splits those cores by thread name (env-* are an actor's environments,
unet-batch its U-Net's batching, ppo-batching the learner's PPO batches,
ppo-training and unet-training its trainers with the threads they started, receive-loop its receive loop), which
tells the work from threads that only spin or wait. The counters of each
window's ends stay beside the run's log (counters-start.json, counters-end.json).

Options:
  --settings LIST   comma-separated AxK pairs (default 2x1,1x2)
  --warmup S        seconds before counting (default 60: builds, first weights,
                    first episodes)
  --seconds S       seconds counted (default 180)
  --runs-dir DIR    where the runs go (default runs/throughput-<time>)
  --port PORT       the learners' HTTP port (default 9480)
  -h, --help        this help
Everything after `--` goes to every local.sh run, e.g.
  deploy/throughput.sh --settings 1x1,1x8,2x8 -- --bin-dir target/release \
    --device gpu --image-size 64 --episode-steps 100
Runs are stopped with SIGTERM (final checkpoint and all); their directories stay.
USAGE
}

SETTINGS="2x1,1x2" WARMUP=60 SECONDS_COUNTED=180 RUNS="" PORT=9480
PASS=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --settings) SETTINGS="${2:?--settings needs a list}"; shift 2 ;;
    --warmup) WARMUP="${2:?--warmup needs seconds}"; shift 2 ;;
    --seconds) SECONDS_COUNTED="${2:?--seconds needs seconds}"; shift 2 ;;
    --runs-dir) RUNS="${2:?--runs-dir needs a directory}"; shift 2 ;;
    --port) PORT="${2:?--port needs a number}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; PASS=("$@"); break ;;
    *) echo "throughput.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ "$SETTINGS" =~ ^[1-9][0-9]*x[1-9][0-9]*(,[1-9][0-9]*x[1-9][0-9]*)*$ ]] \
  || { echo "throughput.sh: --settings needs AxK pairs like 2x1,1x2, got '$SETTINGS'" >&2; exit 2; }
for n in "$WARMUP" "$SECONDS_COUNTED" "$PORT"; do
  [[ "$n" =~ ^[0-9]+$ ]] || { echo "throughput.sh: '$n' is not a whole number" >&2; exit 2; }
done
[[ "$SECONDS_COUNTED" -gt 0 ]] || { echo "throughput.sh: --seconds must be above 0" >&2; exit 2; }

cd "$(dirname "$0")/.."
command -v curl >/dev/null || { echo "throughput.sh: needs curl (sudo apt-get install curl)" >&2; exit 1; }
command -v python3 >/dev/null || { echo "throughput.sh: needs python3" >&2; exit 1; }
[[ -n "$RUNS" ]] || RUNS="runs/throughput-$(date -u +%Y%m%dT%H%M%SZ)"
mkdir -p "$RUNS"

# The counters of /api/status the table is made of, and the CPU seconds of
# each learner and actor process under the run (pid -> [name, seconds]), as
# one JSON line.
counters() {
  curl -fsS "http://127.0.0.1:$PORT/api/status" | python3 -c '
import json, os, sys, time
s = json.load(sys.stdin)
procs = {}
for d in filter(str.isdigit, os.listdir("/proc")):
    try:
        stat = open(f"/proc/{d}/stat").read()
    except OSError:
        continue  # gone since the listing
    name = stat[stat.index("(") + 1:stat.rindex(")")]
    f = stat[stat.rindex(")") + 2:].split()
    procs[d] = (f[1], name, (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK"))
under, grew = {sys.argv[1]}, True
while grew:
    more = {d for d, (ppid, _, _) in procs.items() if ppid in under} - under
    under |= more
    grew = bool(more)
cpu = {d: [procs[d][1], procs[d][2]] for d in under
       if d in procs and procs[d][1] in ("learner", "actor")}
# Per thread of those processes: pid/tid -> [process name, thread name, seconds].
threads = {}
for d, (name, _) in cpu.items():
    try:
        tids = os.listdir(f"/proc/{d}/task")
    except OSError:
        continue
    for t in tids:
        try:
            stat = open(f"/proc/{d}/task/{t}/stat").read()
        except OSError:
            continue
        f = stat[stat.rindex(")") + 2:].split()
        threads[f"{d}/{t}"] = [name, stat[stat.index("(") + 1:stat.rindex(")")],
                               (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")]
print(json.dumps({"t": time.time(), "steps": s["env_steps"], "updates": s["updates"],
  "frames": s["frames_received"], "skipped": s["frames_skipped"],
  "discarded": s.get("rollout_steps_discarded", 0), "dropped": s["dropped"],
  "messages": sum(s["received"].values()), "cpu": cpu, "threads": threads,
  "receiving": s.get("receive_loop_seconds", 0.0),
  "long": s.get("receive_loop_long_passes", 0), "longest": s.get("receive_loop_longest_pass_s", 0.0),
  "lost": s.get("dropped_by_kind", {})}))' "$RUN_PID"
}

RUN_PID=""
stop_run() {
  [[ -n "$RUN_PID" ]] || return 0
  kill -TERM "$RUN_PID" 2>/dev/null || true
  wait "$RUN_PID" 2>/dev/null || true
  RUN_PID=""
}
trap 'stop_run' EXIT
trap 'stop_run; exit 130' INT TERM

ROWS=() THREAD_ROWS=()
IFS=',' read -ra PAIRS <<<"$SETTINGS"
for pair in "${PAIRS[@]}"; do
  actors=${pair%x*} envs=${pair#*x}
  run="$RUNS/${actors}x${envs}"
  echo "== $actors actor(s) x $envs environment(s): $run" >&2
  # A background job ignores SIGINT, so local.sh is stopped with SIGTERM.
  deploy/local.sh --actors "$actors" --envs-per-actor "$envs" --run-dir "$run" \
    --port "$PORT" "${PASS[@]}" >"$run.log" 2>&1 &
  RUN_PID=$!
  up=0
  for _ in $(seq 1 3000); do
    if curl -fsS "http://127.0.0.1:$PORT/healthz" >/dev/null 2>&1; then up=1; break; fi
    kill -0 "$RUN_PID" 2>/dev/null || break
    sleep 0.2
  done
  if [[ $up -eq 0 ]]; then
    echo "throughput.sh: the run did not come up; see $run.log:" >&2
    tail -n 20 "$run.log" >&2
    stop_run
    exit 1
  fi
  sleep "$WARMUP"
  counters >"$run.counters-start.json"
  sleep "$SECONDS_COUNTED"
  counters >"$run.counters-end.json"
  stop_run
  ROWS+=("$(python3 -c "
import json, os
a, b = (json.load(open('$run.counters-' + end + '.json')) for end in ('start', 'end'))
d = {k: b[k] - a[k] for k in a if k not in ('cpu', 'threads', 'lost', 'longest')}
s = d['t']
sent = d['messages'] + d['dropped']
lost = ', '.join('%s %d' % (k, n - a['lost'].get(k, 0))
                 for k, n in sorted(b['lost'].items()) if n > a['lost'].get(k, 0))
# A process started within the window (a restarted actor) counts in full.
busy = {'learner': 0.0, 'actor': 0.0}
for pid, (name, secs) in b['cpu'].items():
    busy[name] += secs - a['cpu'].get(pid, [name, 0.0])[1]
print('| $actors | $envs | %.1f | %.1f | %.2f | %d / %d | %d | %d (%.2f %%%s) | %.0f %% (%d over 0.1 s, longest %.2f s) | %.1f / %.1f of %d |' % (
    d['steps'] / s, d['steps'] / s / $actors, d['updates'] / s, d['frames'], d['skipped'],
    d['discarded'], d['dropped'], 100.0 * d['dropped'] / max(sent, 1), lost and ': ' + lost,
    100.0 * d['receiving'] / s, d['long'], b['longest'],
    busy['learner'] / s, busy['actor'] / s, len(os.sched_getaffinity(0))))")")
  THREAD_ROWS+=("$(python3 -c "
import json, re
a, b = (json.load(open('$run.counters-' + end + '.json')) for end in ('start', 'end'))
s = b['t'] - a['t']
# Threads grouped by process kind and name, numbers stripped (env-3 -> env-*);
# a thread started within the window counts in full.
groups = {}
for key, (kind, name, secs) in b['threads'].items():
    group = groups.setdefault((kind, re.sub(r'[0-9]+', '*', name)), [0, 0.0])
    group[0] += 1
    group[1] += secs - a['threads'].get(key, [kind, name, 0.0])[2]
for kind in ('learner', 'actor'):
    busiest = sorted(((v[1] / s, n, v[0]) for (k, n), v in groups.items() if k == kind), reverse=True)
    shown = ', '.join('%s %.2f (%d)' % (n, c, t) for c, n, t in busiest[:8] if c >= 0.005)
    print('| $actors | $envs | %s | %s |' % (kind, shown or 'none busy'))")")
done

echo "| actors | environments each | steps/s taken, all actors | per actor process | PPO updates/s | U-Net frames taken / skipped | rollout steps discarded | messages lost in transit | learner's receive loop busy | CPU cores busy: learner / actors |"
echo "|---|---|---|---|---|---|---|---|---|---|"
printf '%s\n' "${ROWS[@]}"
echo
echo "Cores each kind of thread kept busy over the window (threads of that name, numbers as *; in brackets: how many):"
echo
echo "| actors | environments each | process | busiest threads: cores (threads) |"
echo "|---|---|---|---|"
printf '%s\n' "${THREAD_ROWS[@]}"
