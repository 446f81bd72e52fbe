#!/usr/bin/env bash
# Packs a run directory into parts of at most 16 MiB, so that a run can move
# between machines (a preemptible or time-limited GPU machine, a file store
# with a size limit) and be resumed there: deploy/unpack-run.sh puts it back.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/pack-run.sh --run-dir DIR --out PACK_DIR [options]

Packs the run in DIR into PACK_DIR as <run>.tar.part-0000, -0001, ... (each at
most --part-size) and <run>.sha256 (every part's sha256 and the run's name).
Carry PACK_DIR to another machine, then:

  deploy/unpack-run.sh --pack PACK_DIR --into runs/
  deploy/local.sh --actors N --run-dir runs/<run> --resume

What a pack holds: config.toml, join.key (the run's secret: keep the parts
where you would keep the key), history.jsonl, the newest checkpoint that
verifies against its manifest (every kept one with --all-checkpoints), the
TensorBoard events and the validation scores. Not the logs (--with-logs adds
them) nor http.addr. Stop the run first (Ctrl-C, --max-steps or
--max-seconds): a learner writing a checkpoint while it is packed is refused.

Options:
  --run-dir DIR       the run to pack (required)
  --out PACK_DIR      where the parts go (required; created; must not hold a
                      pack of the same run already unless --replace)
  --part-size SIZE    largest part, as split(1) reads it (default 16M)
  --all-checkpoints   every kept checkpoint, not only the newest
  --with-logs         the run's logs/ too
  --replace           overwrite an earlier pack of this run in PACK_DIR
  -h, --help          this text
USAGE
}

RUN_DIR="" OUT="" PART_SIZE=16M ALL=0 LOGS=0 REPLACE=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --run-dir) RUN_DIR="${2:?--run-dir needs a directory}"; shift 2 ;;
    --out) OUT="${2:?--out needs a directory}"; shift 2 ;;
    --part-size) PART_SIZE="${2:?--part-size needs a size, e.g. 16M}"; shift 2 ;;
    --all-checkpoints) ALL=1; shift ;;
    --with-logs) LOGS=1; shift ;;
    --replace) REPLACE=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "pack-run.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ -n "$RUN_DIR" && -n "$OUT" ]] || { echo "pack-run.sh: --run-dir and --out are required" >&2; usage >&2; exit 2; }
[[ -d "$RUN_DIR" ]] || { echo "pack-run.sh: no run directory $RUN_DIR" >&2; exit 2; }
[[ -f "$RUN_DIR/config.toml" ]] || { echo "pack-run.sh: $RUN_DIR has no config.toml: is it a run directory?" >&2; exit 2; }
[[ "$PART_SIZE" =~ ^[1-9][0-9]*[KMG]?$ ]] || { echo "pack-run.sh: --part-size needs a size such as 16M, 512K or 1G, got '$PART_SIZE'" >&2; exit 2; }
RUN_DIR="$(cd "$RUN_DIR" && pwd)"
RUN="$(basename "$RUN_DIR")"

# A running learner writes checkpoints and history while we read them.
if [[ -s "$RUN_DIR/logs/learner.pid" ]] && kill -0 "$(cat "$RUN_DIR/logs/learner.pid")" 2>/dev/null; then
  echo "pack-run.sh: the run's learner is running (pid $(cat "$RUN_DIR/logs/learner.pid")): stop it first (Ctrl-C, --max-seconds)" >&2
  exit 3
fi

# Whether checkpoint directory $1 matches its manifest (sizes and sha256).
verifies() { "$(dirname "$0")/verify-checkpoint.py" "$1" >/dev/null; }

members=(config.toml)
for f in join.key history.jsonl tensorboard validation; do
  [[ -e "$RUN_DIR/$f" ]] && members+=("$f")
done
[[ $LOGS -eq 1 && -d "$RUN_DIR/logs" ]] && members+=(logs)
mapfile -t steps < <(find "$RUN_DIR/checkpoints" -mindepth 1 -maxdepth 1 -type d -printf '%f\n' 2>/dev/null | grep -E '^[0-9]+$' | sort -rn)
kept=()
for step in "${steps[@]}"; do
  if verifies "$RUN_DIR/checkpoints/$step"; then
    kept+=("checkpoints/$step")
    [[ $ALL -eq 1 ]] || break
  else
    echo "pack-run.sh: checkpoint $step does not match its manifest: left out" >&2
  fi
done
if [[ ${#kept[@]} -eq 0 ]]; then
  echo "pack-run.sh: warning: $RUN_DIR has no checkpoint that verifies; the pack resumes as a fresh start" >&2
fi
members+=("${kept[@]}")

mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
if compgen -G "$OUT/$RUN.tar.part-*" >/dev/null || [[ -e "$OUT/$RUN.sha256" ]]; then
  [[ $REPLACE -eq 1 ]] || { echo "pack-run.sh: $OUT already holds a pack of $RUN: --replace overwrites it" >&2; exit 2; }
  rm -f "$OUT/$RUN".tar.part-* "$OUT/$RUN.sha256"
fi

tar -C "$RUN_DIR" -cf - "${members[@]}" | split -a 4 -d -b "$PART_SIZE" - "$OUT/$RUN.tar.part-"
(
  cd "$OUT"
  {
    echo "# run $RUN packed $(date -u +%Y-%m-%dT%H:%M:%SZ) by deploy/pack-run.sh"
    sha256sum "$RUN".tar.part-*
  } > "$RUN.sha256.tmp"
  mv "$RUN.sha256.tmp" "$RUN.sha256"
)
parts=$(compgen -G "$OUT/$RUN.tar.part-*" | wc -l)
bytes=$(cat "$OUT/$RUN".tar.part-* | wc -c)
echo "packed $RUN into $parts part(s) of at most $PART_SIZE ($bytes bytes) in $OUT:"
printf '  %s\n' "${members[@]}"
echo "on the other machine: deploy/unpack-run.sh --pack $OUT --into runs/"
