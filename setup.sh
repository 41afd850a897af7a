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
# scikit-sparse's CHOLMOD builds against SuiteSparse.
if ! dpkg -s libllvm19 libsuitesparse-dev >/dev/null 2>&1; then
  echo "== installing system packages: libllvm19 libsuitesparse-dev"
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 libsuitesparse-dev
fi

echo "== installing the Python package (editable) and its dependencies"
python3 -m pip install -q --disable-pip-version-check -e ".[dev]"

echo "== checking the renderer's libLLVM"
python3 -c "import tactip_sim.llvm as l; print('   Dr.Jit will use', l.ensure_llvm())"

if [ "$RUN" = 1 ]; then
  echo "== main job on scenes/shadow_fingertip.toml"
  tactip mesh scenes/shadow_fingertip.toml
fi
