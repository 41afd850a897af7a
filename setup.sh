#!/usr/bin/env bash
# One command on a fresh Debian machine: system packages, the Python package and its
# dependencies, then the main job on the bundled default scene (scenes/shadow_fingertip.toml).
#   ./setup.sh            install + run the main job (output in out/)
#   ./setup.sh --no-run   install only (used by CI)
set -euo pipefail
cd "$(dirname "$0")"
RUN=1
[ "${1:-}" = "--no-run" ] && RUN=0
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"

# Dr.Jit's LLVM backend needs a libLLVM it can use (Debian 12's 14-16 abort at the first render);
# scikit-sparse's CHOLMOD builds against SuiteSparse, and runs 6x faster on OpenBLAS than on the
# reference BLAS it would otherwise link (the FEM precompute: 20 s instead of 2 minutes).
PKGS="libllvm19 libsuitesparse-dev libopenblas0-pthread"
if ! dpkg -s $PKGS >/dev/null 2>&1; then
  echo "== installing system packages: $PKGS"
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $PKGS
fi

echo "== installing the Python package (editable) and its dependencies"
python3 -m pip install -q --disable-pip-version-check -e ".[dev]"

echo "== checking the renderer's libLLVM"
python3 -c "import tactip_sim.llvm as l; print('   Dr.Jit will use', l.ensure_llvm())"

if [ "$RUN" = 1 ]; then
  echo "== main job: the calibration protocol on scenes/shadow_fingertip.toml (resumable: rerun"
  echo "   ./setup.sh after an interruption and it continues where it stopped)"
  python3 -m tactip_sim.commands mesh scenes/shadow_fingertip.toml
  # the defaults: the 60 frames of a sample averaged as one image, caps drawn by the raster
  # layer (docs/speed.md); add --fidelity paper for the paper's frame-by-frame averaging
  python3 -m tactip_sim.commands calibrate scenes/shadow_fingertip.toml --out out/calibration --workers 2
fi
