# Shared by deploy/local.sh and deploy/actors.sh, which source it: running a
# process under supervision and waiting for processes to end. Needs LOGS,
# STOP_FILE and SETUP_FAILED set by the caller before `supervise` runs.

# A log without the stack backtraces that follow an error (RUST_BACKTRACE):
# what a user needs to see is the error above them.
without_backtrace() { sed '/^Stack backtrace:$/,/^$/d; /^stack backtrace:$/,/^$/d'; }

# supervise NAME LABEL READY WHEN CMD...: runs CMD (log LOGS/NAME.log, pid in
# LOGS/NAME.pid) until STOP_FILE appears, restarting it with back-off after
# an abnormal exit. An error exit before its log shows READY is a setup
# problem (data, Vulkan, config, a taken port), not a crash: restarting
# would only repeat it, so it is said (WHEN names the moment, e.g. "before
# it received its first weights") with the end of the log, SETUP_FAILED is
# created and it is not restarted. Status 75 (EX_TEMPFAIL: an actor found
# every publisher slot of a service taken, by another process or by a
# crashed one not yet cleaned up) is a condition to wait out: it is said
# and retried with back-off, whenever it happens.
supervise() {
  local name=$1 label=$2 ready=$3 when=$4 restarts=0 backoff=1 code log start
  shift 4
  log="$LOGS/$name.log"
  while :; do
    start=$(stat -c %s "$log" 2>/dev/null || echo 0)
    "$@" >>"$log" 2>&1 &
    echo $! >"$LOGS/$name.pid"
    code=0; wait $! || code=$?
    [[ -e "$STOP_FILE" ]] && return 0
    if [[ $code -eq 0 ]]; then echo "$label finished"; return 0; fi
    if [[ $code -eq 75 ]]; then
      echo "$label could not join: every publisher slot of a service is taken (see $log); retrying in ${backoff}s"
      sleep "$backoff"
      backoff=$((backoff * 2 > 30 ? 30 : backoff * 2))
      continue
    fi
    if [[ $code -lt 128 ]] && ! tail -c +"$((start + 1))" "$log" | grep -q "$ready"; then
      {
        echo "${0##*/}: $label exited with status $code $when: a setup problem, not a crash, so it is not restarted. The end of $log:"
        tail -c +"$((start + 1))" "$log" | without_backtrace | tail -n 15 | sed 's/^/    /'
      } >&2
      touch "$SETUP_FAILED"
      return 1
    fi
    restarts=$((restarts + 1))
    echo "$label exited with status $code; restart #$restarts in ${backoff}s (log: $log)"
    sleep "$backoff"
    backoff=$((backoff * 2 > 30 ? 30 : backoff * 2))
  done
}

# Waits until the given processes are gone (at most 60 s). Polling instead of
# `wait`: bash's `wait` on a child that was killed while a trap ran (e.g.
# `pkill -f deploy/local.sh`, which also hits the supervisor subshells) never returns.
wait_gone() {
  local pid=""
  for _ in $(seq 1 600); do
    for pid in "$@"; do kill -0 "$pid" 2>/dev/null && break; pid=""; done
    [[ -z "$pid" ]] && return 0
    sleep 0.1
  done
  echo "${0##*/}: processes $* still running after 60 s; going on" >&2
}
