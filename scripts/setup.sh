#!/usr/bin/env bash
# Installs what zona needs on Debian 12 (apt), then the project's Python environment .venv
# (a plain venv of Debian's python3, filled from PyPI with python/requirements.txt: nanobind for
# the Python module, numpy, pytest, matplotlib, h5py and meshio). libhdf5-dev is for the XDMF +
# HDF5 frame output (output.format "xdmf"; zona builds without it and refuses that format);
# libsuitesparse-dev (CHOLMOD, with OpenBLAS under it) is the static solver's direct oracle.
# Idempotent: installs only what is missing.
set -euo pipefail

packages=(
  build-essential cmake pkg-config git
  libeigen3-dev libglm-dev nlohmann-json3-dev libcli11-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libvulkan-dev glslc libglfw3-dev libstb-dev mesa-vulkan-drivers vulkan-validationlayers
  libimgui-dev fonts-dejavu-core
  libhdf5-dev libsuitesparse-dev libopenblas0-pthread
  python3 python3-matplotlib python3-numpy python3-dev python3-venv
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

# The Python environment: Debian's interpreter (not whichever python3 is first on the PATH), no
# system site packages (PyPI's numpy beside Debian's matplotlib breaks it). Refilled when
# python/requirements.txt changes.
cd "$(dirname "$0")/.."
requirements=python/requirements.txt
if [ ! -x .venv/bin/python ]; then
  /usr/bin/python3 -m venv .venv
fi
if ! cmp -s "$requirements" .venv/zona-requirements.txt; then
  echo "zona setup: installing $requirements into .venv" >&2
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r "$requirements"
  cp "$requirements" .venv/zona-requirements.txt
fi
echo "zona setup: dependencies present" >&2
