#!/usr/bin/env bash
# Fuzzes every input parser with libFuzzer for SECONDS in all (default 3600), split evenly
# between the targets (all ten, or those named):
#     scripts/fuzz.sh [SECONDS] [toml gltf glb xml ply obj exr hdr npy vol]
# It installs the nightly toolchain and cargo-fuzz where they are missing. Seeds are the
# bundled and test files of each format; the corpus grows in fuzz/corpus/TARGET. A crash
# is kept in fuzz/artifacts/TARGET/: copy it to tests/data/fuzz/TARGET/ as a regression file
# once it is fixed. The table at the end gives each target's executions.
set -euo pipefail
cd "$(dirname "$0")/.."
total=${1:-3600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(toml gltf glb xml ply obj exr hdr npy vol)

rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
command -v cargo-fuzz > /dev/null || cargo install cargo-fuzz
# No sanitizer (the parsers are safe Rust; it runs 2-3x faster); debug assertions on, so
# that integer overflow is a crash.
cargo +nightly fuzz build -s none -a

per=$((total / ${#targets[@]}))
mkdir -p fuzz/logs
summary=()
failed=0
for t in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$t"
    find scenes tests/data -type f -iname "*.$t" -exec cp -n {} "fuzz/corpus/$t/" \;
    status=0
    # The binary itself, not `cargo fuzz run`: edits made while it runs don't rebuild it.
    mkdir -p "fuzz/artifacts/$t"
    "fuzz/target/x86_64-unknown-linux-gnu/release/$t" "fuzz/corpus/$t" -artifact_prefix="fuzz/artifacts/$t/" \
        -max_total_time="$per" -rss_limit_mb=2048 -timeout=20 -max_len=262144 -print_final_stats=1 \
        > "fuzz/logs/$t.log" 2>&1 || status=$?
    runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "fuzz/logs/$t.log" | grep -o '[0-9]*$' || echo '?')
    result=ok
    if [ "$status" -ne 0 ]; then
        result="CRASH (fuzz/logs/$t.log, fuzz/artifacts/$t/)"
        failed=1
    fi
    summary+=("$(printf '%-5s %6ss %12s executions  %s' "$t" "$per" "$runs" "$result")")
    echo "${summary[-1]}"
done
rm -rf /tmp/vkinverse-fuzz-*
echo
printf '%s\n' "${summary[@]}"
exit $failed
