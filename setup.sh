#!/usr/bin/env bash
# One-command, idempotent set-up of a fresh Debian 12 machine for bracketry (rig software, emulator, tests).
# Installs the Debian packages, creates .venv with the project (editable, all extras) and the MicroPython
# WebAssembly runtime (npm) under .venv/micropython-wasm. Prints each step; fails loudly naming the failing step.
# ./setup.sh --rig: the backpack's computer only (Aravis, serial tools, the trigger firmware's toolchain and flasher;
# .venv with the host extra): no emulator, Slurm, munge, Chromium, torch, QEMU or Node.
set -Eeuo pipefail
cd "$(dirname "$0")"
ROOT=$(pwd)
STEP="start"
trap 'echo "setup.sh: FAILED at step: $STEP" >&2' ERR
step() { STEP="$1"; echo "==> $1"; }
SUDO=""; if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
ROLE=all
case "${1:-}" in
  "") ;;
  --rig) ROLE=rig ;;
  *) echo "usage: ./setup.sh [--rig]   (--rig: the backpack's computer only)" >&2; exit 2 ;;
esac

APT_PACKAGES=(libaravis-0.8-0 gir1.2-aravis-0.8 aravis-tools aravis-tools-cli libgirepository1.0-dev
  libcairo2-dev pkg-config gcc make socat gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm
  iproute2 util-linux python3-venv python3-dev chromium libdeflate-dev
  libgl1 libegl1 libopengl0 libsm6 libice6 libx11-6 libxext6  # the OpenGL/X11 runtime libraries pyorbslam3 links
  slurm-wlm munge)  # a one-node Slurm the cluster tests start (bracketry benchmark --cluster slurm)
RIG_APT_PACKAGES=(libaravis-0.8-0 gir1.2-aravis-0.8 aravis-tools aravis-tools-cli libgirepository1.0-dev
  libcairo2-dev pkg-config gcc make socat gcc-arm-none-eabi libnewlib-arm-none-eabi stlink-tools
  iproute2 util-linux python3-venv python3-dev)
if [ "$ROLE" = rig ]; then
  APT_PACKAGES=("${RIG_APT_PACKAGES[@]}")
else
  # pdflatex with booktabs (texlive-latex-recommended) and amssymb (texlive-base): the report's LaTeX tables compiled
  APT_PACKAGES+=(texlive-latex-base texlive-latex-recommended texlive-fonts-recommended)
  command -v node >/dev/null 2>&1 || APT_PACKAGES+=(nodejs)
  command -v npm >/dev/null 2>&1 || APT_PACKAGES+=(npm)
fi

step "Debian packages"
missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "    installing: ${missing[*]}"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
else
  echo "    all present"
fi

step "Python virtual environment (.venv)"
PY=${PYTHON:-python3}
"$PY" -c 'import sys; assert sys.version_info >= (3, 11), "Python >= 3.11 needed"'
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip 'setuptools>=74.1' wheel

if [ "$ROLE" = rig ]; then
  step "Python packages (editable install, host extra)"
  stamp=.venv/.bracketry-installed-rig
  if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q -e '.[host]'
    touch "$stamp"
  else
    echo "    up to date"
  fi
  step "bracketry doctor"
  .venv/bin/bracketry doctor || echo "    (doctor reported missing components; see above)"
  STEP="done"
  echo "==> rig set-up complete in ${SECONDS}s (activate with: source $ROOT/.venv/bin/activate)"
  exit 0
fi

step "Python packages (editable install with all extras)"
stamp=.venv/.bracketry-installed
# (re)install when pyproject.toml or a C extension's source changed, or a built extension is missing
lut12_src=emulator/bracketry_emulator/emulation/_lut12.c
zhang_src=emulator/bracketry_emulator/ae/_zhang_terms.c
pngcodec_src=emulator/bracketry_emulator/dataset/_pngcodec.c
kernels_src=emulator/bracketry_emulator/ae/_upstream_kernels.c
synth_src=emulator/bracketry_emulator/synth/_kernels.c
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$lut12_src" -nt "$stamp" ] \
   || [ "$zhang_src" -nt "$stamp" ] || [ "$pngcodec_src" -nt "$stamp" ] || [ "$kernels_src" -nt "$stamp" ] \
   || [ "$synth_src" -nt "$stamp" ] \
   || ! ls emulator/bracketry_emulator/emulation/_lut12*.so >/dev/null 2>&1 \
   || ! ls emulator/bracketry_emulator/ae/_zhang_terms*.so >/dev/null 2>&1 \
   || ! ls emulator/bracketry_emulator/dataset/_pngcodec*.so >/dev/null 2>&1 \
   || ! ls emulator/bracketry_emulator/ae/_upstream_kernels*.so >/dev/null 2>&1 \
   || ! ls emulator/bracketry_emulator/synth/_kernels*.so >/dev/null 2>&1; then
  .venv/bin/python -m pip install -q -e '.[all]'
  touch "$stamp"
else
  echo "    up to date"
fi

step "MicroPython WebAssembly runtime (npm, .venv/micropython-wasm)"
MPY_DIR=.venv/micropython-wasm
if [ ! -f "$MPY_DIR/node_modules/@micropython/micropython-webassembly-pyscript/micropython.mjs" ]; then
  mkdir -p "$MPY_DIR"
  (cd "$MPY_DIR" && { [ -f package.json ] || npm init -y >/dev/null; } \
     && npm install --no-audit --no-fund '@micropython/micropython-webassembly-pyscript@^1.27.0' >/dev/null)
else
  echo "    present"
fi

step "bracketry doctor"
.venv/bin/bracketry doctor || echo "    (doctor reported missing components; see above)"
STEP="done"
echo "==> setup complete in ${SECONDS}s (activate with: source $ROOT/.venv/bin/activate)"
