#!/usr/bin/env bash
# Instructions a render executes per sample per pixel, counted by valgrind (cachegrind
# without its cache simulation): deterministic, unlike timings on a busy machine, so two
# builds can be compared to a fraction of a per cent (experiments/lavapipe-speed.md, "Counting
# instructions instead of timing"). Two renders at SPP1 and SPP2 samples per pixel; their
# difference over SPP2 - SPP1 leaves out start-up (shader compilation, scene upload).
#
#   scripts/instructions.sh BINARY SCENE [FILM] [SPP1] [SPP2]
#   scripts/instructions.sh target/release/vkinverse scenes/cornell/scene.toml 64x64 4 36
#   EXTRA_ARGS="--max-depth 2" scripts/instructions.sh ...   (more `render` arguments)
set -euo pipefail
if [ $# -lt 2 ]; then
    echo "usage: $0 BINARY SCENE [FILM] [SPP1] [SPP2]" >&2
    exit 2
fi
bin=$1 scene=$2 film=${3:-64x64} spp1=${4:-4} spp2=${5:-36}
command -v valgrind >/dev/null || { echo "error: valgrind is not installed (apt install valgrind)" >&2; exit 1; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
count() {
    # One lavapipe thread; no shader cache, so both renders compile the same kernels.
    MESA_SHADER_CACHE_DISABLE=true LP_NUM_THREADS=1 valgrind --tool=cachegrind --cache-sim=no \
        --cachegrind-out-file=/dev/null "$bin" render "$scene" --spp "$1" --film "$film" --quiet \
        ${EXTRA_ARGS:-} -o "$out/render.exr" 2>&1 | sed -n 's/.*I *refs: *\([0-9,]*\).*/\1/p' | tr -d ,
}
a=$(count "$spp1")
b=$(count "$spp2")
[ -n "$a" ] && [ -n "$b" ] || { echo "error: no instruction count from valgrind" >&2; exit 1; }
echo "$scene $film: $(( (b - a) / (spp2 - spp1) )) instructions per spp ($a at $spp1 spp, $b at $spp2)"
