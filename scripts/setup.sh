#!/usr/bin/env bash
# Idempotent set-up for GRT: a .venv with the Python packages, and (where no GPU driver exists)
# Mesa's lavapipe Vulkan driver from bookworm-backports, which SAPIEN needs even for state-only envs.
#
#   scripts/setup.sh            # create/refresh .venv and the Vulkan driver
#   GRT_TORCH="torch==2.13.0" scripts/setup.sh   # the default pin, the CPU build from PyTorch's CPU index
#   GRT_TORCH="torch" scripts/setup.sh           # e.g. GPU users: let pip pick a CUDA build (default index)
#   scripts/setup.sh --motionplanning            # also ManiSkill's motion planners (make motionplanning)
#
# Re-running is cheap: every step checks whether it is already done.
set -euo pipefail
cd "$(dirname "$0")/.."

MOTIONPLANNING=0
for arg in "$@"; do
  case "$arg" in
    --motionplanning) MOTIONPLANNING=1 ;;
    *) printf 'usage: scripts/setup.sh [--motionplanning]\n' >&2; exit 2 ;;
  esac
done

PY=${PYTHON:-python3}
VENV=${GRT_VENV:-.venv}
TORCH_SPEC=${GRT_TORCH:-torch==2.13.0}
STAMP="$VENV/.grt-setup-stamp"

log() { printf '\033[1;34m[setup]\033[0m %s\n' "$*"; }
die() { printf '\033[1;31m[setup] error:\033[0m %s\n' "$*" >&2; exit 1; }

# ---------------------------------------------------------------- Vulkan (SAPIEN needs a device)
have_vulkan_device() {
  # A GPU driver or a recent lavapipe: look for an ICD file whose driver library exists.
  local f lib
  for f in /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json /usr/local/share/vulkan/icd.d/*.json; do
    [ -f "$f" ] || continue
    lib=$(sed -n 's/.*"library_path": *"\([^"]*\)".*/\1/p' "$f")
    case "$f" in *lvp_icd*) mesa_ok || continue ;; esac
    [ -n "$lib" ] && { [ -f "$lib" ] || ldconfig -p | grep -q "$(basename "$lib")"; } && return 0
  done
  return 1
}
mesa_ok() {
  # SAPIEN needs lavapipe from Mesa >= 24.3 (VK_KHR_external_semaphore_fd).
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3
}
install_lavapipe() {
  if ! command -v apt-get >/dev/null 2>&1; then
    die "no Vulkan device found and this is not a Debian/Ubuntu system.
  SAPIEN (the simulator) needs a Vulkan driver: install your GPU's driver, or Mesa >= 24.3 with
  lavapipe (Fedora: 'dnf install mesa-vulkan-drivers vulkan-loader'; Arch: 'pacman -S vulkan-swrast
  vulkan-icd-loader'), then re-run this script."
  fi
  local SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  . /etc/os-release
  if [ "${VERSION_CODENAME:-}" = "bookworm" ]; then
    if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
      log "adding bookworm-backports (for Mesa 25.x lavapipe)"
      echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee /etc/apt/sources.list.d/grt-backports.list >/dev/null
    fi
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t bookworm-backports \
      mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  fi
  mesa_ok || die "installed Mesa $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers) but SAPIEN needs >= 24.3;
  on Ubuntu use 24.10+ or the kisak-mesa PPA; on Debian 12 enable bookworm-backports."
}

if [ "${GRT_SKIP_VULKAN:-0}" = 1 ]; then
  log "GRT_SKIP_VULKAN=1: not checking for a Vulkan driver"
elif have_vulkan_device; then
  log "Vulkan driver present"
else
  log "no usable Vulkan driver: installing Mesa lavapipe (CPU)"
  install_lavapipe
fi

# ---------------------------------------------------------------- Python environment
$PY -c 'import sys; assert sys.version_info >= (3, 10), sys.version' 2>/dev/null \
  || die "Python >= 3.10 is needed (found: $($PY --version 2>&1)); set PYTHON=/path/to/python3.1x"
if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV"
  $PY -m venv "$VENV" || die "could not create a venv: on Debian/Ubuntu 'apt-get install python3-venv'"
fi
# Contact-GraspNet's pretrained weights come in the cgn-pytorch wheel (20 MB, MIT). The wheel pins
# years-old exact numpy/torch/scipy/trimesh and imports meshcat: GRT reads only its weights file and runs
# its own implementation of the network (grt/policies/cgn_net.py), so it is installed without deps.
CGN_SPEC="cgn-pytorch==0.4.3"
HASH=$( (cat pyproject.toml; echo "$TORCH_SPEC $CGN_SPEC") | sha256sum | cut -c1-16)
TORCH_CPU_INDEX=${GRT_TORCH_INDEX:-https://download.pytorch.org/whl/cpu}
install_torch() {
  # The default pin takes the CPU build from PyTorch's CPU index (the default index's Linux torch is the CUDA
  # build, several GB); where that index cannot be reached, the default index's (which may be a CUDA build).
  # GRT_TORCH set by the user (a CUDA torch): the default index, as asked.
  if [ -z "${GRT_TORCH:-}" ] && "$VENV/bin/python" -c "import urllib.request, sys; urllib.request.urlopen(sys.argv[1] + '/torch/', timeout=15)" "$TORCH_CPU_INDEX" >/dev/null 2>&1; then
    log "torch: $TORCH_SPEC from PyTorch's CPU index ($TORCH_CPU_INDEX)"
    "$VENV/bin/python" -m pip install -q --index-url "$TORCH_CPU_INDEX" "$TORCH_SPEC" && return 0
    log "torch: PyTorch's CPU index failed: falling back to the default index"
  elif [ -z "${GRT_TORCH:-}" ]; then
    log "torch: PyTorch's CPU index ($TORCH_CPU_INDEX) cannot be reached: $TORCH_SPEC from the default index"
  fi
  "$VENV/bin/python" -m pip install -q "$TORCH_SPEC"
}
torch_build() {
  "$VENV/bin/python" -c 'import torch; print(f"torch {torch.__version__}, the " + (f"CUDA {torch.version.cuda} build" if torch.version.cuda else "CPU build"))'
}
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ]; then
  log "Python packages up to date ($VENV)"
else
  log "installing Python packages into $VENV (torch: $TORCH_SPEC)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  # torch first and pinned: an unpinned torch (pulled by a dependency) fetches GBs of CUDA wheels.
  install_torch
  "$VENV/bin/python" -m pip install -q -e ".[dev]"
  "$VENV/bin/python" -m grt.setup cgn   # Contact-GraspNet's weights (cgn-pytorch without its pins)
  echo "$HASH" > "$STAMP"
fi
log "installed: $(torch_build)"
# Optional: Debian's Chromium, which the report's browser test (tests/report/test_browser.py) drives
# headless; without it that test is skipped. Never fails the set-up.
if [ "${GRT_SKIP_CHROMIUM:-0}" != 1 ] && ! command -v chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  log "installing chromium (optional, for the report's browser test; GRT_SKIP_CHROMIUM=1 skips it)"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  { $SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
    || log "chromium could not be installed: the browser test will be skipped"
fi
# ---------------------------------------------------------------- motion planning (opt-in)
# ManiSkill's motion-planning solutions (policy=motion_planner) need mplib, which ManiSkill installs (0.1.1),
# but every mplib wheel (0.1.0, 0.1.1, 0.2.1) crashes in Planner() under numpy 2. numpy 1.26.4 goes into a
# folder of its own that only the simulator workers running that policy put first on their path
# (grt/evaluators/worker_env.py); GRT's main process keeps its numpy 2.
MP_DIR=${GRT_MOTIONPLANNING_DIR:-.motionplanning}
if [ "$MOTIONPLANNING" = 1 ]; then
  # the same command an installed GRT's user runs (python -m grt.setup motionplanning), into the checkout's folder
  "$VENV/bin/python" -m grt.setup motionplanning --dir "$MP_DIR" || die "motion planning: the set-up above failed"
fi
log "done: $(torch_build) | grt $("$VENV/bin/python" -c 'import grt; print(grt.__version__)')"
