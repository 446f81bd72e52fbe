#!/usr/bin/env bash
# Puts back a run that deploy/pack-run.sh packed into parts, after checking
# every part and every checkpoint, so that it resumes on this machine.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/unpack-run.sh --pack PACK_DIR --into DIR [options]

Checks every part in PACK_DIR against its <run>.sha256, joins them and unpacks
the run into DIR/<run>, then checks each checkpoint against its manifest.
Nothing is written until every part checks. Then resume it:

  deploy/local.sh --actors N --run-dir DIR/<run> --resume

Options:
  --pack PACK_DIR   where deploy/pack-run.sh put the parts (required)
  --into DIR        the directory the run goes into (required; e.g. runs/)
  --run NAME        which run, when PACK_DIR holds packs of several
  --replace         DIR/<run> exists (an older copy of the run): move it aside
                    to DIR/<run>.before-unpack-<time> and unpack in its place
  -h, --help        this text
USAGE
}

PACK="" INTO="" RUN="" REPLACE=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --pack) PACK="${2:?--pack needs a directory}"; shift 2 ;;
    --into) INTO="${2:?--into needs a directory}"; shift 2 ;;
    --run) RUN="${2:?--run needs a run name}"; shift 2 ;;
    --replace) REPLACE=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "unpack-run.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
[[ -n "$PACK" && -n "$INTO" ]] || { echo "unpack-run.sh: --pack and --into are required" >&2; usage >&2; exit 2; }
[[ -d "$PACK" ]] || { echo "unpack-run.sh: no pack directory $PACK" >&2; exit 2; }
PACK="$(cd "$PACK" && pwd)"

if [[ -z "$RUN" ]]; then
  mapfile -t sums < <(cd "$PACK" && compgen -G "*.sha256" || true)
  case ${#sums[@]} in
    0) echo "unpack-run.sh: $PACK holds no pack (no <run>.sha256 from deploy/pack-run.sh)" >&2; exit 2 ;;
    1) RUN="${sums[0]%.sha256}" ;;
    *) echo "unpack-run.sh: $PACK holds packs of several runs (${sums[*]%.sha256}): choose one with --run" >&2; exit 2 ;;
  esac
fi
SUMS="$PACK/$RUN.sha256"
[[ -f "$SUMS" ]] || { echo "unpack-run.sh: no $SUMS" >&2; exit 2; }

# Every part listed is there and checks, and no part is there unlisted.
listed=$(grep -v '^#' "$SUMS" | awk '{print $2}' | sort)
present=$(cd "$PACK" && compgen -G "$RUN.tar.part-*" | sort || true)
if [[ "$listed" != "$present" ]]; then
  echo "unpack-run.sh: the parts in $PACK are not those $RUN.sha256 lists:" >&2
  diff <(echo "$listed") <(echo "$present") | sed -n 's/^< /  missing: /p; s/^> /  not listed: /p' >&2 || true
  exit 4
fi
if ! (cd "$PACK" && grep -v '^#' "$RUN.sha256" | sha256sum --check --quiet --strict -) >&2; then
  echo "unpack-run.sh: a part of $RUN is damaged (above): copy it again; nothing was unpacked" >&2
  exit 4
fi

mkdir -p "$INTO"
INTO="$(cd "$INTO" && pwd)"
TARGET="$INTO/$RUN"
if [[ -e "$TARGET" ]]; then
  [[ $REPLACE -eq 1 ]] || { echo "unpack-run.sh: $TARGET exists: --replace moves it aside and unpacks in its place" >&2; exit 2; }
  if [[ -s "$TARGET/logs/learner.pid" ]] && kill -0 "$(cat "$TARGET/logs/learner.pid")" 2>/dev/null; then
    echo "unpack-run.sh: $TARGET's learner is running: stop it first" >&2; exit 3
  fi
fi
STAGE="$(mktemp -d "$INTO/.unpack-$RUN.XXXXXX")"
trap 'rm -rf "$STAGE"' EXIT
(cd "$PACK" && cat $(grep -v '^#' "$RUN.sha256" | awk '{print $2}')) | tar -C "$STAGE" -xf -

# Each checkpoint against its manifest (what `learner serve --resume` checks too).
bad=""
if [[ -d "$STAGE/checkpoints" ]]; then
  bad=$("$(dirname "$0")/verify-checkpoint.py" "$STAGE"/checkpoints/*/ || true)
fi
if [[ -n "$bad" ]]; then
  echo "unpack-run.sh: checkpoints that do not match their manifest: $bad; nothing was unpacked" >&2
  exit 4
fi

if [[ -e "$TARGET" ]]; then
  aside="$TARGET.before-unpack-$(date +%s)"
  mv "$TARGET" "$aside"
  echo "moved the earlier copy aside to $aside"
fi
mv "$STAGE" "$TARGET"
trap - EXIT
steps=$(ls "$TARGET/checkpoints" 2>/dev/null | grep -E '^[0-9]+$' | sort -n | tail -n 1 || true)
echo "unpacked $RUN into $TARGET${steps:+ (newest checkpoint: step $steps)}"
echo "resume it: deploy/local.sh --actors N --run-dir $TARGET --resume"
