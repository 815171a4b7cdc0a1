#!/usr/bin/env bash
# Every measurement BENCHMARKS.md reports, one after the other, on one
# machine in one run: the "Measuring again" list of BENCHMARKS.md as a
# script (`make benchmarks`). Nothing else should run on the machine
# meanwhile. On 2 cores with llvmpipe it takes about 80 minutes, and the
# codec step about 45 minutes more (it records 90 versions of four scenes
# under two scripts at about 4.5 s a version, and caches the recordings in
# bench-out/codec/recordings/).
#
#   client/bench/report.sh                       # everything, into target/bench-report
#   OUT=target/r2 ONLY="solve dynamic" client/bench/report.sh
#   LEVELS=/path/to/levels client/bench/report.sh  # section 9 (default ../shared/levels)
#   MESH_CHARTS="pairs triangles" ONLY=meshes client/bench/report.sh
#
# Steps (ONLY takes their names): solve accuracy dynamic roundtrip latency
# codec viewers relay soak meshes seams lights levels. It builds first (release, the
# binaries, examples and test binaries it runs) so that no build runs beside
# a measurement; each step's output goes to OUT/NAME.txt, with the time it
# started, its load average and its duration in OUT/steps.tsv.
set -euo pipefail
cd "$(dirname "$0")/../.."

OUT=${OUT:-target/bench-report}
ONLY=${ONLY:-"solve accuracy dynamic roundtrip latency codec viewers relay soak meshes seams lights levels"}
LEVELS=${LEVELS:-../shared/levels}
# The chart modes of `bench meshes`; BENCHMARKS.md's older rows (pairs,
# triangles, the latter also without clusters) take up to 120 s per size
# each.
MESH_CHARTS=${MESH_CHARTS:-"lightmap-uvs generated parallelograms"}
BIN=target/release
mkdir -p "$OUT"

wanted() { [[ " $ONLY " == *" $1 "* ]]; }

{
  echo "commit $(git rev-parse --short HEAD)$(git diff --quiet || echo ' (with local changes)')"
  echo "date $(date -u +%FT%TZ)"
  grep -m1 'model name' /proc/cpuinfo
  echo "cpus $(nproc)"
} > "$OUT/machine.txt"

echo "building (release)" >&2
cargo build --release --workspace --bins --examples >&2
cargo test --release -p lightwire-solve --test accuracy --test path_tracer --test textures --no-run >&2
cargo test -p lightwire-solve --test round_trip --no-run >&2
vulkaninfo --summary 2>/dev/null | grep -m1 deviceName >> "$OUT/machine.txt" || true

printf 'step\tstarted\tload average\tseconds\tstatus\n' > "$OUT/steps.tsv"
# step NAME COMMAND...: runs COMMAND with its output in OUT/NAME.txt.
step() {
  local name=$1
  shift
  local start load status=ok
  start=$(date +%s)
  load=$(cut -d' ' -f1-3 /proc/loadavg)
  echo "[$(date +%T)] $name: $*" >&2
  echo "\$ $*" >> "$OUT/$name.txt"
  "$@" >> "$OUT/$name.txt" 2>&1 || status="failed ($?)"
  printf '%s\t%s\t%s\t%s\t%s\n' "$name" "$(date -d "@$start" +%T)" "$load" \
    "$(($(date +%s) - start))" "$status" >> "$OUT/steps.tsv"
}

# serve_and_load NAME SCENE LOAD-ARGS...: a server of its own for one load run.
serve_and_load() {
  local name=$1 scene=$2
  shift 2
  "$BIN/lightwire" serve --dev --listen 127.0.0.1:0 --scene "$scene" \
    > "$OUT/$name.serve.out" 2> "$OUT/$name.serve.err" &
  local server=$! addr=""
  for _ in $(seq 1 600); do
    addr=$(sed -n 's#^lightwire listening on http://\([^ ]*\).*#\1#p' "$OUT/$name.serve.out")
    [ -n "$addr" ] && curl -sf "http://$addr/readyz" > /dev/null && break
    sleep 0.1
  done
  step "$name" "$BIN/lightwire-client" load "http://$addr" "$@" --report "$OUT/$name.json"
  kill "$server" 2> /dev/null || true
  wait "$server" 2> /dev/null || true
}

if wanted solve; then
  step solve "$BIN/lightwire" bench solve
  step solve-glb "$BIN/lightwire" bench solve --scene scenes/meshes/cornell-large.glb --density-scale 0.5
  for c in lightmap-uvs generated parallelograms; do
    step "solve-atrium-$c" "$BIN/lightwire" bench solve --scene scenes/meshes/atrium.glb --density-scale 0.3 --charts "$c"
  done
fi
if wanted accuracy; then
  step accuracy-tests cargo test --release -p lightwire-solve --test accuracy --test path_tracer --test textures -- --nocapture
  step pt-cornell-large "$BIN/examples/solvers_vs_path_tracer" scenes/cornell-large.json 0.35
  step pt-cornell-blocks "$BIN/examples/solvers_vs_path_tracer" scenes/cornell-blocks.json 0.5
fi
if wanted dynamic; then
  for s in cornell-low cornell-large cornell-small indirect-light; do
    step "dynamic-$s" "$BIN/lightwire" bench dynamic --scene "scenes/$s.json" --methods progressive,incremental,cross --frames 5
  done
  step dynamic-gather "$BIN/lightwire" bench dynamic --frames 5 --methods gather
  step dynamic-glb "$BIN/lightwire" bench dynamic --scene scenes/meshes/cornell-dynamic.glb --methods progressive,cross --frames 5
fi
if wanted roundtrip; then
  for s in cornell-low cornell-large; do
    step "roundtrip-$s-cross" "$BIN/examples/round_trip" "scenes/$s.json"
    step "roundtrip-$s-incremental" "$BIN/examples/round_trip" "scenes/$s.json" --methods incremental --jumps 16
  done
  step roundtrip-settled cargo test -p lightwire-solve --test round_trip a_settled_scene -- --nocapture
fi
if wanted latency; then
  serve_and_load latency-cornell-low scenes/cornell-low.json --scene cornell-low \
    --script scenes/scripts/orbit.json --drivers 1 --viewers 100 --rate 30 --duration 20s
  serve_and_load latency-cornell-large scenes/cornell-large.json --scene cornell-large \
    --script scenes/scripts/orbit.json --drivers 1 --viewers 10 --rate 10 --duration 20s
  serve_and_load bandwidth-cornell-large scenes/cornell-large.json --scene cornell-large \
    --script scenes/scripts/rotate.json --drivers 1 --viewers 10 --rate 30 --duration 20s
fi
if wanted codec; then
  step codec "$BIN/lightwire" bench codec --tile-sizes 8,16 --levels 3,9 --json "$OUT/codec.json"
fi
if wanted viewers; then
  step viewers env NS="1 100 400 800 1600" REPS=3 SKIP_BUILD=1 OUT="$OUT/load-ladder" client/bench/load-ladder.sh
fi
if wanted relay; then
  step relay "$BIN/examples/relay_bench" --viewers 250,350,500,750 --duration 10
  step relay-light "$BIN/examples/relay_bench" --viewers 1000 --duration 10 --light-viewers
fi
if wanted soak; then
  step soak client/bench/soak.sh --out "$OUT/soak"
fi
if wanted meshes; then
  for c in $MESH_CHARTS; do
    step "meshes-$c" "$BIN/lightwire" bench meshes --triangles 1000,10000,100000 --max-seconds 120 --charts "$c"
  done
  # A patch per triangle, also without its shooting clusters.
  if [[ " $MESH_CHARTS " == *" triangles "* ]]; then
    step meshes-no-clusters "$BIN/lightwire" bench meshes --triangles 1000,10000,100000 --max-seconds 120 --charts triangles --no-clusters
  fi
fi
if wanted seams; then
  step seams-10 "$BIN/examples/seam_cost" 10
  step seams-20 "$BIN/examples/seam_cost" 20
fi
if wanted lights; then
  step lights "$BIN/lightwire" bench lights --json "$OUT/lights.json"
fi
# serve_until_idle NAME SCENE ID: a server of its own on SCENE until its
# solver is idle (refined and corrected: `lightwire_solver_idle` 1), the
# seconds that took in OUT/NAME.txt and the lightmap it then serves in
# OUT/NAME.exr.
serve_until_idle() {
  local name=$1 scene=$2 id=$3 start
  start=$(date +%s)
  echo "\$ lightwire serve --dev --scene $scene, until lightwire_solver_idle{scene=\"$id\"} is 1" >> "$OUT/$name.txt"
  env LEVELS="${LEVELS:-}" "$BIN/lightwire" serve --dev --listen 127.0.0.1:0 --scene "$scene" \
    > "$OUT/$name.serve.out" 2> "$OUT/$name.serve.err" &
  local server=$! addr="" idle=""
  for _ in $(seq 1 36000); do
    addr=$(sed -n 's#^lightwire listening on http://\([^ ]*\).*#\1#p' "$OUT/$name.serve.out")
    if [ -n "$addr" ]; then
      idle=$(curl -sf "http://$addr/metrics" | sed -n "s/^lightwire_solver_idle{scene=\"$id\"} //p")
      [ "$idle" = 1 ] && break
    fi
    sleep 0.1
  done
  if [ "$idle" = 1 ]; then
    echo "idle after $(($(date +%s) - start)) s (from the server's start)" >> "$OUT/$name.txt"
    # Past `settle_ms` (500 ms): texels the encoder held back within its
    # error budget are sent once the solver is idle.
    sleep 1.5
    curl -sf "http://$addr/api/scenes/$id/lightmap.exr" -o "$OUT/$name.exr"
  else
    echo "not idle within an hour" >> "$OUT/$name.txt"
  fi
  kill "$server" 2> /dev/null || true
  wait "$server" 2> /dev/null || true
}

if wanted levels; then
  if [ -d "$LEVELS" ]; then
    for l in garage pandora zdm2; do
      step "levels-validate-$l" env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" validate "scenes/levels/$l.json"
    done
    step levels-bake-garage env LEVELS="$LEVELS" "$BIN/lightwire" bake --scene scenes/levels/garage.json \
      --solver progressive --tolerance 1e-2 --out "$OUT/garage-progressive"
    step levels-eye-garage env LEVELS="$LEVELS" "$BIN/lightwire" bench eye --scene scenes/levels/garage.json \
      --lightmap "$OUT/garage-progressive/lightmap.exr" --points 2000 --spp 8192
    for l in garage pandora; do
      step "levels-bake-rays-$l" env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" bake \
        --scene "scenes/levels/$l.json" --solver rays --tolerance 1e-3 --out "$OUT/$l-rays"
    done
    step levels-eye-rays-garage env LEVELS="$LEVELS" "$BIN/lightwire" bench eye --scene scenes/levels/garage.json \
      --lightmap "$OUT/garage-rays/lightmap.exr" --points 2000 --spp 8192
    # The levels under the lights a level brings (issue 59): zdm2 under a
    # sun and a sky, pandora under point and spot lights.
    for l in zdm2-sky pandora-lamps; do
      step "levels-bake-rays-$l" env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" bake \
        --scene "scenes/levels/$l.json" --solver rays --tolerance 1e-3 --out "$OUT/$l-rays"
    done
    step levels-eye-rays-zdm2-sky env LEVELS="$LEVELS" "$BIN/lightwire" bench eye --scene scenes/levels/zdm2-sky.json \
      --lightmap "$OUT/zdm2-sky-rays/lightmap.exr" --points 1000 --spp 16384
    step levels-eye-rays-pandora-lamps env LEVELS="$LEVELS" "$BIN/lightwire" bench eye \
      --scene scenes/levels/pandora-lamps.json --lightmap "$OUT/pandora-lamps-rays/lightmap.exr" --points 1000 --spp 8192 --seed 1
    # The same without texels near the lights (`light_detail` 0): what the
    # refinement buys, at the same points.
    sed -e "s#\"file\": \"../../../shared/levels/#\"file\": \"$(realpath "$LEVELS")/#" \
      -e 's#"texel_density": 1,#"texel_density": 1, "light_detail": 0,#' \
      scenes/levels/pandora-lamps.json > "$OUT/pandora-lamps-detail0.json"
    step levels-bake-rays-pandora-lamps-detail0 /usr/bin/time -v "$BIN/lightwire" bake \
      --scene "$OUT/pandora-lamps-detail0.json" --solver rays --tolerance 1e-3 --out "$OUT/pandora-lamps-detail0-rays"
    step levels-eye-rays-pandora-lamps-detail0 "$BIN/lightwire" bench eye --scene "$OUT/pandora-lamps-detail0.json" \
      --lightmap "$OUT/pandora-lamps-detail0-rays/lightmap.exr" --points 1000 --spp 8192 --seed 1
    # Twice the texel density: what the representation of the light, not
    # the solver, still costs where a player looks.
    step levels-bake-rays-garage-x2 env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" bake \
      --scene scenes/levels/garage.json --solver rays --tolerance 1e-3 --density-scale 2 --out "$OUT/garage-rays-x2"
    step levels-eye-rays-garage-x2 env LEVELS="$LEVELS" "$BIN/lightwire" bench eye --scene scenes/levels/garage.json \
      --density-scale 2 --lightmap "$OUT/garage-rays-x2/lightmap.exr" --points 2000 --spp 8192
    # Lightmap UVs by the uvunwrap crate beside the projection (the
    # default): charts, atlas and elements on every level, and the garage
    # at the eye at three seeds of points, each the same for both.
    for l in garage pandora zdm2; do
      step "levels-validate-uvunwrap-$l" env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" validate \
        --charts uvunwrap "scenes/levels/$l.json"
    done
    step levels-bake-rays-garage-uvunwrap env LEVELS="$LEVELS" /usr/bin/time -v "$BIN/lightwire" bake \
      --scene scenes/levels/garage.json --solver rays --tolerance 1e-3 --charts uvunwrap --out "$OUT/garage-rays-uvunwrap"
    for seed in 2 3; do
      step "levels-eye-rays-garage-seed$seed" env LEVELS="$LEVELS" "$BIN/lightwire" bench eye \
        --scene scenes/levels/garage.json --lightmap "$OUT/garage-rays/lightmap.exr" --points 2000 --spp 8192 --seed $seed
    done
    for seed in 1 2 3; do
      step "levels-eye-rays-garage-uvunwrap-seed$seed" env LEVELS="$LEVELS" "$BIN/lightwire" bench eye \
        --scene scenes/levels/garage.json --charts uvunwrap --lightmap "$OUT/garage-rays-uvunwrap/lightmap.exr" \
        --points 2000 --spp 8192 --seed $seed
    done
    step levels-dynamic-garage env LEVELS="$LEVELS" "$BIN/lightwire" bench dynamic \
      --scene scenes/levels/garage.json --methods cross --frames 10 --out "$OUT/dynamic-levels"
    serve_until_idle levels-serve-garage scenes/levels/garage.json garage
    LEVELS="$LEVELS" serve_and_load levels-latency-garage scenes/levels/garage.json --scene garage \
      --script scenes/scripts/garage/rotate.json --drivers 1 --viewers 10 --rate 10 --duration 60s
    step levels-eye-served-garage env LEVELS="$LEVELS" "$BIN/lightwire" bench eye \
      --scene scenes/levels/garage.json --lightmap "$OUT/levels-serve-garage.exr" --points 2000 --spp 8192
  else
    echo "no levels at $LEVELS: section 9 skipped" >&2
  fi
fi
echo "done: $OUT/steps.tsv" >&2
column -t -s$'\t' "$OUT/steps.tsv" >&2
