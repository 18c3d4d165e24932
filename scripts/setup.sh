#!/usr/bin/env bash
# Installs what zona needs on Debian 12 (apt). Idempotent: installs only what is missing.
set -euo pipefail

packages=(
  build-essential cmake pkg-config git
  libeigen3-dev libglm-dev nlohmann-json3-dev libcli11-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libvulkan-dev glslc libglfw3-dev libstb-dev mesa-vulkan-drivers vulkan-validationlayers
  libimgui-dev fonts-dejavu-core
  python3 python3-venv
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if ((${#missing[@]})); then
  echo "zona setup: installing ${missing[*]}" >&2
  sudo_cmd=()
  if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi
# The plots' Python (python/zona_plot.py, docs/plots.md): the project environment .venv, with
# matplotlib from PyPI (python/plot_requirements.txt).
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
[ -x "$root/.venv/bin/python" ] || python3 -m venv "$root/.venv"
"$root/.venv/bin/python" -c 'import matplotlib' 2>/dev/null ||
  "$root/.venv/bin/pip" install -q -r "$root/python/plot_requirements.txt"
echo "zona setup: dependencies present" >&2
