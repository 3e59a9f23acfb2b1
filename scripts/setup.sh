#!/usr/bin/env bash
# One-time (idempotent) set-up on a fresh Debian/Ubuntu machine:
#  - Mesa's software Vulkan driver (headless GGUI rendering without a GPU), Xvfb (demo tests) and
#    headless Chromium (the gallery page's browser test, tests/test_gallery.py; about 96 MB,
#    measured 14 s with apt-get update on the dev machine), installed through apt only where missing;
#  - a virtual environment .venv with requirements.txt.
# Usage: bash scripts/setup.sh     (then use .venv/bin/python)
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
for pkg in mesa-vulkan-drivers libvulkan1 xvfb chromium-headless-shell; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "setup: installing ${need[*]} (apt)" >&2
  $sudo apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv" >&2
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --disable-pip-version-check -r requirements.txt
