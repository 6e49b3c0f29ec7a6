#!/usr/bin/env bash
# Install everything voe_lightning needs on a fresh Debian/Ubuntu machine: the EGL libraries for
# headless MuJoCo rendering, headless Chromium for the browser test of a report's index.html,
# a CPU build of PyTorch (unless one is installed), then the package.
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
APT_UPDATED=""
apt_install() {
  [ -n "$APT_UPDATED" ] || { $SUDO apt-get update -qq; APT_UPDATED=1; }
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
if ! { ldconfig -p 2>/dev/null | grep -q libEGL_mesa && compgen -G "/usr/lib/*/dri/swrast_dri.so" >/dev/null; }; then
  apt_install libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libopengl0 libglvnd0
fi
# Debian's names; where apt has no such packages (Ubuntu ships Chromium as a snap) the browser
# test of index.html (tests/report/test_html.py) is skipped, and nothing else needs them.
if ! { command -v chromium && command -v chromedriver; } >/dev/null 2>&1; then
  apt_install chromium chromium-driver ||
    echo "install.sh: apt could not install chromium chromium-driver; the browser test of index.html will be skipped" >&2
fi

# pip must be there; a system Python marked EXTERNALLY-MANAGED (PEP 668: Debian 12, Ubuntu
# 23.04 and later) refuses it outside a virtual environment, which pip says and we explain.
VENV_HINT="make a virtual environment (python3 -m venv .venv && . .venv/bin/activate), then rerun"
if ! python3 -m pip --version >/dev/null 2>&1; then
  echo "install.sh: $(command -v python3) has no pip; install it (apt-get install python3-pip) or $VENV_HINT" >&2
  exit 1
fi
pip_install() {
  local log status=0
  log=$(mktemp)
  python3 -m pip install -q "$@" 2>"$log" || status=$?
  cat "$log" >&2
  if [ "$status" -ne 0 ] && grep -q "externally-managed-environment" "$log"; then
    echo "install.sh: $(command -v python3) is managed by the system (PEP 668); $VENV_HINT" >&2
  fi
  rm -f "$log"
  return "$status"
}

# torch first, pinned, and the CPU build from PyTorch's own index, so pip does not pull the
# multi-GB CUDA build from the default index as a dependency. A torch already installed is kept.
# Where that index cannot be reached (a machine without internet), pip's configured index is
# used instead: there it must offer a CPU wheel (as this project's machines do, locally).
TORCH="torch==2.13.0"
CPU_INDEX="https://download.pytorch.org/whl/cpu"
if ! python3 -c "import torch" 2>/dev/null; then
  if python3 -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=15)" \
      "$CPU_INDEX/" 2>/dev/null; then
    pip_install "$TORCH" --index-url "$CPU_INDEX"
  else
    echo "install.sh: $CPU_INDEX cannot be reached; installing $TORCH from pip's configured index" >&2
    pip_install "$TORCH"
  fi
fi
pip_install -e ".[test]"
python3 -c "import voe_lightning, mujoco, torch; print('voe_lightning', voe_lightning.__version__, '| mujoco', mujoco.__version__, '| torch', torch.__version__)"
