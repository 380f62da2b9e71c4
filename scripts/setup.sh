#!/usr/bin/env bash
# Installs what vkinverse needs on Debian/Ubuntu: the Vulkan loader, Mesa's lavapipe (a
# CPU Vulkan driver, so no GPU is needed), the validation layers used by the tests, and
# the shader compiler libraries that build.rs links (shaderc, glslang, SPIRV-Tools), and
# Python's venv and pip for the Python package (python/).
set -euo pipefail
packages=(mesa-vulkan-drivers libvulkan1 vulkan-validationlayers libshaderc-dev glslang-dev spirv-tools fonts-dejavu-core python3-venv python3-pip)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo=sudo
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get update -qq
    $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
    $sudo apt-get clean
fi
command -v cargo >/dev/null || { echo "setup: cargo not found; install Rust (https://rustup.rs) first" >&2; exit 1; }
