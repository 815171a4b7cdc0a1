#!/usr/bin/env bash
# The soak benchmark of docs/benchmarks-history.md ("Soak"): a solver, a relay in front
# of it, N viewers and K drivers on the relay for DURATION seconds on
# loopback; it stops by itself.
#
#   client/bench/soak.sh                        # 500 viewers, 2 drivers, 600 s
#   client/bench/soak.sh --duration 60 --out target/soak-short
#   client/bench/soak.sh --viewers 100 --serve-flags "--density-scale 0.5"
#
# It builds nothing: it runs target/release/lightwire and
# target/release/lightwire-client (`cargo build --release --workspace`, or
# `make build`, first). Every SAMPLE seconds it records the resident set
# (VmRSS), open descriptors and threads of the solver, the relay and the
# load tester (samples.csv); the load tester reports latency percentiles,
# errors, versions skipped and reconnects per INTERVAL (load.json,
# load.log) and, at the end, compares every viewer's lightmap with a fresh
# keyframe taken from the solver directly. summary.md has the tables.
#
# Needs bash, awk and a Linux /proc; no curl, jq or Python.
set -euo pipefail
cd "$(dirname "$0")/../.."

DURATION=600
VIEWERS=500
DRIVERS=2
RATE=30
SAMPLE=10
INTERVAL=60
WARMUP=60
SCENE=scenes/cornell-low.json
SCRIPT=scenes/scripts/orbit.json
SERVE_FLAGS=""
OUT=target/soak
BIN=${LIGHTWIRE_BIN:-target/release}

usage() {
  sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'
  cat <<EOF

Options (defaults in brackets):
  --duration SECS     how long the drivers drive [$DURATION]
  --viewers N         viewers on the relay [$VIEWERS]
  --drivers K         drivers on the relay [$DRIVERS]
  --rate HZ           poses per second per driver [$RATE]
  --sample SECS       RSS / descriptor sampling period [$SAMPLE]
  --interval SECS     latency / error reporting period [$INTERVAL]
  --warmup SECS       growth is measured from the sample this long after the
                      load tester starts [$WARMUP]
  --scene FILE        [$SCENE]
  --script FILE       the drivers' transform script [$SCRIPT]
  --serve-flags STR   extra flags for \`lightwire serve\` (default: none, as \`make run\`:
                      the GPU progressive solver, cross redistribution)
  --out DIR           where the logs and the report go [$OUT]
EOF
}

while [ $# -gt 0 ]; do
  case "$1" in -h|--help) ;; *) [ $# -ge 2 ] || { echo "soak: $1 needs a value (see --help)" >&2; exit 2; } ;; esac
  case "$1" in
    --duration) DURATION=$2; shift 2 ;;
    --viewers) VIEWERS=$2; shift 2 ;;
    --drivers) DRIVERS=$2; shift 2 ;;
    --rate) RATE=$2; shift 2 ;;
    --sample) SAMPLE=$2; shift 2 ;;
    --interval) INTERVAL=$2; shift 2 ;;
    --warmup) WARMUP=$2; shift 2 ;;
    --scene) SCENE=$2; shift 2 ;;
    --script) SCRIPT=$2; shift 2 ;;
    --serve-flags) SERVE_FLAGS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "soak: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
for n in "$DURATION" "$VIEWERS" "$DRIVERS" "$SAMPLE" "$INTERVAL" "$WARMUP"; do
  [[ "$n" =~ ^[0-9]+$ ]] || { echo "soak: $n is not a whole number" >&2; exit 2; }
done
[ "$SAMPLE" -ge 1 ] && [ "$INTERVAL" -ge 1 ] && [ "$DURATION" -ge 1 ] \
  || { echo "soak: --duration, --sample and --interval must be at least 1" >&2; exit 2; }

for b in lightwire lightwire-client; do
  [ -x "$BIN/$b" ] || {
    echo "soak: $BIN/$b not found; build it first: cargo build --release --workspace (or make build)" >&2
    exit 2
  }
done
[ -f "$SCENE" ] || { echo "soak: no scene file $SCENE" >&2; exit 2; }
[ -f "$SCRIPT" ] || { echo "soak: no script file $SCRIPT" >&2; exit 2; }

# Descriptors: the relay and the load tester each hold one socket per
# client, plus their own files; leave room.
need=$(( VIEWERS + DRIVERS + 256 ))
if [ "$(ulimit -n)" != unlimited ] && [ "$(ulimit -n)" -lt "$need" ]; then
  hard=$(ulimit -Hn)
  if [ "$hard" = unlimited ] || [ "$hard" -ge "$need" ]; then
    echo "soak: raising the open-file limit from $(ulimit -n) to $need for $VIEWERS viewers" >&2
    ulimit -n "$need"
  else
    echo "soak: $VIEWERS viewers need about $need open files, but the hard limit is $hard; raise it (limits.conf, or run fewer --viewers)" >&2
    exit 2
  fi
fi

mkdir -p "$OUT"
rm -f "$OUT"/{solver,relay,load}.{out,err} "$OUT"/load.{json,log} "$OUT"/samples.csv "$OUT"/summary.md

PIDS=()
cleanup() {
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${PIDS[@]}"; do
    for _ in $(seq 1 50); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null || true
  done
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Waits for "... listening on http://ADDR" in $1, then for GET /readyz to
# answer 200 (at most $2 seconds); prints ADDR.
wait_ready() {
  local file=$1 limit=$2 addr="" status=""
  for _ in $(seq 1 $(( limit * 10 ))); do
    addr=$(sed -n 's#^lightwire.* listening on http://\([^ ]*\).*#\1#p' "$file" | head -1)
    if [ -n "$addr" ]; then
      status=$( (exec 3<>"/dev/tcp/${addr%:*}/${addr##*:}" \
        && printf 'GET /readyz HTTP/1.0\r\nHost: %s\r\n\r\n' "$addr" >&3 \
        && head -1 <&3) 2>/dev/null || true)
      case "$status" in *" 200 "*) echo "$addr"; return 0 ;; esac
    fi
    sleep 0.1
  done
  return 1
}

# The scene's id is its "name" (top level, first in the shipped files).
SCENE_ID=$(sed -n 's/^  "name": *"\([^"]*\)".*/\1/p' "$SCENE" | head -1)
SCENE_ID=${SCENE_ID:-$(basename "$SCENE" .json)}
# shellcheck disable=SC2086
"$BIN/lightwire" serve --dev --listen 127.0.0.1:0 --scene "$SCENE" $SERVE_FLAGS \
  > "$OUT/solver.out" 2> "$OUT/solver.err" &
SOLVER=$!; PIDS+=("$SOLVER")
SOLVER_ADDR=$(wait_ready "$OUT/solver.out" 120) \
  || { echo "soak: the solver did not become ready in 120 s; see $OUT/solver.err" >&2; exit 1; }
"$BIN/lightwire" relay --dev --listen 127.0.0.1:0 \
  --upstream "ws://$SOLVER_ADDR/ws/scenes/$SCENE_ID" \
  > "$OUT/relay.out" 2> "$OUT/relay.err" &
RELAY=$!; PIDS+=("$RELAY")
RELAY_ADDR=$(wait_ready "$OUT/relay.out" 60) \
  || { echo "soak: the relay did not become ready in 60 s; see $OUT/relay.err" >&2; exit 1; }

LOAD_CMD=("$BIN/lightwire-client" load "http://$RELAY_ADDR" --scene "$SCENE_ID"
  --script "$SCRIPT" --viewers "$VIEWERS" --drivers "$DRIVERS" --rate "$RATE"
  --duration "${DURATION}s" --interval "${INTERVAL}s" --settle-timeout 120s
  --verify-url "http://$SOLVER_ADDR" --report "$OUT/load.json")
echo "soak: solver pid $SOLVER http://$SOLVER_ADDR ($BIN/lightwire serve --dev --scene $SCENE $SERVE_FLAGS)" >&2
echo "soak: relay pid $RELAY http://$RELAY_ADDR" >&2
echo "soak: ${LOAD_CMD[*]}" >&2
started=$(date +%s)
"${LOAD_CMD[@]}" > "$OUT/load.out" 2> "$OUT/load.log" &
LOAD=$!; PIDS+=("$LOAD")

# The load tester connects, drives DURATION, settles (at most 120 s) and
# verifies; past this deadline it is stopped and the soak fails.
deadline=$(( started + DURATION + 300 ))
# cpu_s: the process's user + system CPU seconds so far; loadavg and rustc
# (compilers running) say how busy the rest of the machine was.
echo "t_s,process,pid,rss_kib,fds,threads,cpu_s,loadavg,rustc" > "$OUT/samples.csv"
CLK=$(getconf CLK_TCK)
sample() {
  local t=$(( $(date +%s) - started )) name pid rss threads fds cpu load1 rustc
  load1=$(cut -d' ' -f1 /proc/loadavg)
  rustc=$(pgrep -c -x rustc || true)
  for name in solver relay load; do
    case $name in solver) pid=$SOLVER ;; relay) pid=$RELAY ;; load) pid=$LOAD ;; esac
    [ -r "/proc/$pid/status" ] || continue
    rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
    threads=$(awk '/^Threads:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
    fds=$(find "/proc/$pid/fd" -mindepth 1 -maxdepth 1 2>/dev/null | wc -l)
    # Field 2 of /proc/PID/stat is "(comm)"; none of ours has a space in it.
    cpu=$(awk -v c="$CLK" '{printf "%.2f", ($14 + $15) / c}' "/proc/$pid/stat" 2>/dev/null || true)
    [ -n "$rss" ] && echo "$t,$name,$pid,$rss,$fds,$threads,$cpu,$load1,$rustc" >> "$OUT/samples.csv"
  done
}
timed_out=""
next=$started
while kill -0 "$LOAD" 2>/dev/null; do
  now=$(date +%s)
  if [ "$now" -ge "$next" ]; then
    sample
    next=$(( next + SAMPLE ))
    last=$(grep '^load: interval' "$OUT/load.log" | tail -1 || true)
    echo "soak: $(tail -n 3 "$OUT/samples.csv" | awk -F, '{printf "t=%s s %s %d MiB %d fds; ", $1, $2, $4 / 1024, $5}')" >&2
    [ -n "$last" ] && [ "$last" != "${shown:-}" ] && { echo "  $last" >&2; shown=$last; }
  fi
  if [ "$now" -ge "$deadline" ]; then
    echo "soak: the load tester is still running $(( now - started )) s after it started; stopping it" >&2
    timed_out=1
    kill "$LOAD" 2>/dev/null || true
    break
  fi
  sleep 1
done
load_status=0
wait "$LOAD" || load_status=$?

# --- summary.md ---------------------------------------------------------
{
  echo "# Soak: $VIEWERS viewers and $DRIVERS drivers on a relay, ${DURATION} s"
  echo
  echo "Command: \`client/bench/soak.sh --duration $DURATION --viewers $VIEWERS --drivers $DRIVERS --rate $RATE --scene $SCENE${SERVE_FLAGS:+ --serve-flags \"$SERVE_FLAGS\"}\`"
  echo
  echo "Load tester: \`${LOAD_CMD[*]}\`"
  echo
  echo "Machine: $(nproc) CPUs ($(awk -F': ' '/^model name/ {print $2; exit}' /proc/cpuinfo)), $(awk '/^MemTotal/ {printf "%.0f GB", $2 / 1048576}' /proc/meminfo) RAM; load average at the end: $(cut -d' ' -f1-3 /proc/loadavg); $(date -u +%Y-%m-%dT%H:%MZ)."
  echo "Solver adapter: $(sed 's/\x1b\[[0-9;]*m//g' "$OUT/solver.err" "$OUT/solver.out" 2>/dev/null | sed -n 's/.* adapter=\(.*\)$/\1/p' | head -1)"
  echo
  awk -F, 'NR > 1 && $2 == "solver" { n++; l += $8; if ($8 > m) m = $8; if ($9 > 0) busy++ }
    END { if (n) printf "Rest of the machine during the run: load average mean %.1f, max %.1f; rustc running in %d of %d samples.\n", l / n, m, busy, n }' "$OUT/samples.csv"
  echo
  echo "Load tester exit status: $load_status${timed_out:+ (stopped at the deadline)}"
  echo
  summary=$(grep '^load: [0-9]* viewers' "$OUT/load.log" | tail -1 || true)
  verify=$(grep 'bit-exact with' "$OUT/load.log" | tail -1 || true)
  echo "- ${summary:-no summary line in load.log}"
  echo "- ${verify:-no verification line in load.log}"
  grep -E '^  error: |^FAILED' "$OUT/load.log" | head -20 | sed 's/^ */- /' || true
  echo
  echo "## Resident set and descriptors (sampled every $SAMPLE s; t from the load tester's start, which connects for a few seconds before driving)"
  echo
  echo "| process | t warm-up s | t end s | RSS warm-up MiB | RSS end MiB | RSS growth MiB | RSS max MiB | fds warm-up | fds end | fds max | threads end | CPU warm-up to end |"
  echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
  for name in solver relay load; do
    awk -F, -v p="$name" -v w="$WARMUP" '
      $2 == p {
        if (!have_w && $1 >= w) { tw = $1; rw = $4; fw = $5; cw = $7; have_w = 1 }
        re = $4; fe = $5; te = $6; t_end = $1; ce = $7
        if ($4 > rmax) rmax = $4; if ($5 > fmax) fmax = $5
      }
      END {
        if (!have_w) { print "| " p " | (no sample after " w " s) | | | | | | | | | | |"; exit }
        cpu = (t_end > tw) ? sprintf("%.0f%% of a core", 100 * (ce - cw) / (t_end - tw)) : "-"
        printf "| %s | %d | %d | %.1f | %.1f | %+.1f (%+.1f%%) | %.1f | %d | %d | %d | %d | %s |\n",
          p, tw, t_end, rw / 1024, re / 1024, (re - rw) / 1024, 100 * (re - rw) / rw, rmax / 1024, fw, fe, fmax, te, cpu
      }' "$OUT/samples.csv"
  done
  echo
  echo "## Per interval (${INTERVAL} s) of the drive phase, from load.log"
  echo
  echo "| interval | s | latency p50 ms | p95 ms | p99 ms | max ms | samples | versions applied | skipped | errors | reconnects | stale seqs | poses |"
  echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
  awk '/^load: interval [0-9]+ / {
    gsub(/[(),]/, "")
    # load: interval I A-B s: latency p50 X ms p95 X ms p99 X ms max X ms N samples A versions applied B skipped C errors D reconnects E stale F poses
    printf "| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", $3, $4, $8, $11, $14, $17, $19, $21, $24, $26, $28, $30, $32
  }' "$OUT/load.log"
  echo
  echo "Files: samples.csv (every sample), load.json (the full report), load.log, solver.err, relay.err."
} > "$OUT/summary.md"
cat "$OUT/summary.md"
[ -z "$timed_out" ] && [ "$load_status" -eq 0 ] || exit 1
