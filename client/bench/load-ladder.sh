#!/usr/bin/env bash
# The viewer-capacity benchmark of BENCHMARKS.md: `lightwire-client load`
# with one driver at 30 poses/s and an increasing number of viewers against
# a release `lightwire serve` on loopback; median over REPS runs per N of
# the transform-to-delivery latency percentiles, the frame rates, and the
# CPU seconds per second the server and the load tester used.
#
#   client/bench/load-ladder.sh                 # N = 1 25 50 100 200 400 800
#   NS="100 200" REPS=5 client/bench/load-ladder.sh
#   SERVE_FLAGS="--solver progressive" client/bench/load-ladder.sh
#   SKIP_BUILD=1 ...                            # use the release binaries as they are
#   SUMMARY_ONLY=1 OUT=target/bench-load NS="1 100" client/bench/load-ladder.sh   # table only
#
# By default the server runs the cheapest solver configuration (the CPU
# reference solver on cornell-low at a tenth of its texel density, about
# 45 ms per re-solve) so that the fan-out path, not the solver, is what is
# measured; see BENCHMARKS.md for the solver-bound numbers.
set -euo pipefail
cd "$(dirname "$0")/../.."

NS=${NS:-"1 25 50 100 200 400 800"}
REPS=${REPS:-3}
DURATION=${DURATION:-15s}
SCENE=${SCENE:-scenes/cornell-low.json}
SCRIPT=${SCRIPT:-scenes/scripts/orbit.json}
SERVE_FLAGS=${SERVE_FLAGS:-"--solver reference --density-scale 0.1"}
OUT=${OUT:-target/bench-load}
mkdir -p "$OUT"

if [ -z "${SUMMARY_ONLY:-}" ]; then
[ -n "${SKIP_BUILD:-}" ] || cargo build --release -p lightwire-server -p lightwire-client --bins >&2
BIN=target/release

# shellcheck disable=SC2086
"$BIN/lightwire" serve --dev --listen 127.0.0.1:0 $SERVE_FLAGS --scene "$SCENE" \
  > "$OUT/serve.out" 2> "$OUT/serve.err" &
SERVER=$!
trap 'kill $SERVER 2>/dev/null || true' EXIT
for _ in $(seq 1 200); do
  ADDR=$(sed -n 's#^lightwire listening on http://\([^ ]*\).*#\1#p' "$OUT/serve.out")
  [ -n "$ADDR" ] && curl -sf "http://$ADDR/readyz" > /dev/null && break
  sleep 0.1
done
[ -n "${ADDR:-}" ] || { echo "the server did not start; see $OUT/serve.err" >&2; exit 1; }
SCENE_ID=$(curl -sf "http://$ADDR/api/scenes" | jq -r '.[0].id')
CLK=$(getconf CLK_TCK)
cpu_of() { awk '{print $14 + $15}' "/proc/$1/stat"; }

echo "server: $BIN/lightwire serve $SERVE_FLAGS --scene $SCENE (pid $SERVER, http://$ADDR)" >&2
for n in $NS; do
  for rep in $(seq 1 "$REPS"); do
    report="$OUT/n$n-r$rep.json"
    before=$(cpu_of $SERVER)
    start=$(date +%s.%N)
    /usr/bin/time -f "%U %S" -o "$OUT/time" \
      "$BIN/lightwire-client" load "http://$ADDR" --scene "$SCENE_ID" --script "$SCRIPT" \
      --viewers "$n" --drivers 1 --rate 30 --duration "$DURATION" --report "$report" \
      2> "$OUT/n$n-r$rep.log" || true
    wall=$(echo "$(date +%s.%N) - $start" | bc)
    after=$(cpu_of $SERVER)
    jq --argjson s "$(echo "($after - $before) / $CLK / $wall" | bc -l)" \
       --argjson c "$(awk -v w="$wall" '{print ($1 + $2) / w}' "$OUT/time")" \
       '. + {server_cpu_per_s: $s, load_cpu_per_s: $c}' "$report" > "$report.tmp" && mv "$report.tmp" "$report"
    jq -r --arg n "$n" --arg r "$rep" \
      '"N=\($n) run \($r): p50 \(.latency.p50_ms) p99 \(.latency.p99_ms) max \(.latency.max_ms) ms, errors \(.errors), server \(.server_cpu_per_s*100|floor)% load \(.load_cpu_per_s*100|floor)% CPU"' "$report" >&2
  done
done
kill $SERVER 2>/dev/null || true
fi

echo
echo "| viewers | p50 ms | p95 ms | p99 ms | max ms | first viewer p50 / p99 ms | fan-out spread p50 / p99 ms | errors | versions/s per viewer | frames/s (all viewers) | KiB/s (all viewers) | server solve ms | server CPU | load-tester CPU |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for n in $NS; do
  jq -s -r --arg n "$n" '
    def med(f): (map(f) | sort) as $v | $v[(($v | length) - 1) / 2 | floor];
    "| \($n) | \(med(.latency.p50_ms)) | \(med(.latency.p95_ms)) | \(med(.latency.p99_ms)) | \(med(.latency.max_ms)) | \(med(.first_delivery.p50_ms)) / \(med(.first_delivery.p99_ms)) | \(med(.fanout_spread.p50_ms)) / \(med(.fanout_spread.p99_ms)) | \(med(.errors)) | \(med(.versions_per_s_per_viewer) * 10 | floor / 10) | \(med(.frames_per_s) | floor) | \(med(.bytes_per_s / 1024) | floor) | \(med(.server.solve_ms_mean)) | \(med(.server_cpu_per_s * 100) | floor)% | \(med(.load_cpu_per_s * 100) | floor)% |"
  ' "$OUT"/n"$n"-r*.json
done
