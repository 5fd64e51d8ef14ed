#!/usr/bin/env bash
# One-time set-up, safe to rerun: system packages, a virtual environment with pinned packages.
# Used by `make run` and `make test`; a rerun with nothing to do takes about a second.
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi

# libllvm19: Mitsuba's LLVM (CPU) variants JIT-compile with it; the distribution's LLVM 15 aborts.
# The X/GL client libraries are what the bpy wheel links against on a headless machine.
APT_PKGS="libllvm19 libxrender1 libxxf86vm1 libxfixes3 libxi6 libxkbcommon0 libsm6 libgl1 libegl1"
# --test: Chromium as well, for the test that opens the run report in a real browser.
if [ "${1:-}" = "--test" ]; then APT_PKGS="$APT_PKGS chromium"; fi
missing=""
for p in $APT_PKGS; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "setup: installing system packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi

stamp=".venv/.requirements-$(sha256sum requirements.txt pyproject.toml | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ]; then
  echo "setup: installing Python packages (pinned in requirements.txt)"
  .venv/bin/pip install -q --upgrade pip
  # torch first and pinned: an unpinned torch would pull a multi-GB CUDA build.
  .venv/bin/pip install -q "$(grep -E '^torch==' requirements.txt)"
  .venv/bin/pip install -q -r requirements.txt
  .venv/bin/pip install -q --no-deps -e .
  rm -f .venv/.requirements-*
  touch "$stamp"
fi
