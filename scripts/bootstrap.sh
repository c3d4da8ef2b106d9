#!/usr/bin/env bash
# Set up a fresh Debian machine for WonderHuman Studio and run one task.
#   bash scripts/bootstrap.sh demo [ARGS]   the main job on the built-in demo scene
#   bash scripts/bootstrap.sh test [ARGS]   the test suite (pytest ARGS)
#   bash scripts/bootstrap.sh video [VIDEO --out SCENE]   the mediapipe virtualenv (+ prepare a video)
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

# The raw-video detector: mediapipe 0.10.21 (the last release that ships its pose and segmentation
# models) declares numpy<2, the project uses numpy 2, so it gets its own virtualenv .venv-video, which
# `wonderhuman-studio prepare` runs as a subprocess. Its declared jax/jaxlib/sentencepiece/sounddevice
# (~900 MB) are not used by the Pose solution and are left out (~20 s, ~250 MB).
MEDIAPIPE_PIN="mediapipe==0.10.21"
setup_video_venv() {
  local vstamp=".venv-video/.installed-$(echo "$MEDIAPIPE_PIN 1" | sha256sum | cut -c1-16)"
  [ -f "$vstamp" ] && return 0
  [ -x .venv-video/bin/python ] || python3 -m venv .venv-video
  .venv-video/bin/python -m pip install -q --no-deps "$MEDIAPIPE_PIN" >.venv-video/install.log 2>&1 \
    && .venv-video/bin/python -m pip install -q "numpy<2" "protobuf>=4.25.3,<5" absl-py "attrs>=19.1" \
         "flatbuffers>=2.0" opencv-contrib-python matplotlib >>.venv-video/install.log 2>&1 \
    || { cat .venv-video/install.log >&2; echo "installing $MEDIAPIPE_PIN into .venv-video failed" >&2; exit 1; }
  .venv-video/bin/python -c "import mediapipe.python.solutions.pose, mediapipe.python.solutions.selfie_segmentation, mediapipe.python.solutions.hands"
  rm -f .venv-video/.installed-*
  touch "$vstamp"
}

case "$task" in
  demo) exec .venv/bin/wonderhuman-studio demo "$@" ;;
  test)
    setup_video_venv
    export WONDERHUMAN_DETECTOR_PYTHON="$PWD/.venv-video/bin/python" WONDERHUMAN_REQUIRE_DETECTOR=1
    exec .venv/bin/python -m pytest -q "$@" ;;
  video)  # bash scripts/bootstrap.sh video [VIDEO --out SCENE ...]: set up the detector, then prepare
    setup_video_venv
    if (($#)); then exec .venv/bin/wonderhuman-studio prepare --detector-python "$PWD/.venv-video/bin/python" "$@"; fi
    echo "mediapipe is ready in .venv-video; run: .venv/bin/wonderhuman-studio prepare VIDEO --out SCENE" ;;
  *) echo "unknown task '$task' (expected demo, test or video)" >&2; exit 2 ;;
esac
