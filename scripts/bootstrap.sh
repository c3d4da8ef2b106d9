#!/usr/bin/env bash
# Set up a fresh Debian machine for WonderHuman Studio and run one task.
#   bash scripts/bootstrap.sh demo [ARGS]   the main job on the built-in demo scene
#   bash scripts/bootstrap.sh test [ARGS]   the test suite (pytest ARGS)
# Installs the Debian packages for headless OpenGL (EGL, Mesa) and a virtual screen, a virtualenv
# in .venv with the CPU build of torch (pinned: any other spec pulls the CUDA build) and the project.
set -euo pipefail
cd "$(dirname "$0")/.."
task="${1:-test}"
shift || true

apt_packages=(libegl1 libgl1 libgl1-mesa-dri xvfb xauth xdotool python3-venv)
missing=()
for pkg in "${apt_packages[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if ((${#missing[@]})); then
  sudo_cmd=""
  [ "$(id -u)" = 0 ] || sudo_cmd="sudo"
  echo "installing Debian packages: ${missing[*]}"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

TORCH_PIN="torch==2.13.0"
stamp=".venv/.installed-$(cat pyproject.toml scripts/bootstrap.sh | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ]; then
  [ -x .venv/bin/python ] || python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q "$TORCH_PIN"
  .venv/bin/python -m pip install -q -e ".[test]" "$TORCH_PIN"
  rm -f .venv/.installed-*
  touch "$stamp"
fi

case "$task" in
  demo) exec .venv/bin/wonderhuman-studio demo "$@" ;;
  test) exec .venv/bin/python -m pytest -q "$@" ;;
  *) echo "unknown task '$task' (expected demo or test)" >&2; exit 2 ;;
esac
