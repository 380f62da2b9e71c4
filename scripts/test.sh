#!/usr/bin/env bash
# The tests: the Rust suite (cargo test, with any arguments given here), then the Python
# package, built from python/ into .venv with what its tests need (pytest, JAX's CPU
# wheels, and PyTorch: its CPU wheels where that index is reachable, else PyPI's, about
# 5 GB and a minute to install), its tests and its examples at a small scale.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test "$@"
[ -x .venv/bin/python ] || python3 -m venv .venv
# The extension in the dev profile: it reuses what `cargo test` built.
MATURIN_PEP517_ARGS="--profile dev" .venv/bin/pip install -q ./python pytest "jax[cpu]"
# PyTorch where it is missing and the disk has room for it (12 GB free: PyPI's wheels take
# 5 GB, and a release build follows in CI).
frameworks="jax"
free_gb=$(($(df -Pk . | awk 'NR == 2 {print $4}') / 1048576))
if .venv/bin/python -c "import torch" 2> /dev/null; then
    frameworks="jax torch"
elif [ "$free_gb" -ge 12 ] && { .venv/bin/pip install -q --no-cache-dir torch --index-url https://download.pytorch.org/whl/cpu 2> /dev/null \
    || .venv/bin/pip install -q --no-cache-dir torch; }; then
    frameworks="jax torch"
else
    echo "test.sh: PyTorch is not installed (${free_gb} GB free, or its install failed): its test and example are skipped" >&2
fi
# The tests of the frameworks installed fail, rather than skip, where they are missing.
VKINVERSE_REQUIRE_FRAMEWORKS="$frameworks" .venv/bin/python -m pytest -q python/tests
.venv/bin/python examples/cornell_l1.py --iterations 30 --film 32 > /dev/null
.venv/bin/python examples/jax_texture.py --iterations 10 --film 32 > /dev/null
if [ "$frameworks" = "jax torch" ]; then
    .venv/bin/python examples/torch_texture.py --iterations 10 --film 32 > /dev/null
fi
echo "test.sh: Rust suite, Python tests and examples passed"
