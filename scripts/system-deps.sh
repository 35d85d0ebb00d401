#!/usr/bin/env bash
# System packages: SuiteSparse (CHOLMOD, for the sparse Cholesky solver), OpenBLAS,
# Chromium (headless screenshots of the web viewer: `tryon view --screenshot` and its
# test), and the GL and GLib libraries OpenCV loads (mediapipe's person finder imports it). The simulator works without them (it falls back to SciPy's SuperLU), so a machine
# where apt is unavailable or we are not root only gets a note.
set -u
need=()
dpkg -s libsuitesparse-dev >/dev/null 2>&1 || need+=(libsuitesparse-dev)
dpkg -s libopenblas0-pthread >/dev/null 2>&1 || need+=(libopenblas0-pthread)
command -v chromium >/dev/null 2>&1 || need+=(chromium)
dpkg -s libgl1 >/dev/null 2>&1 || need+=(libgl1)
dpkg -s libglib2.0-0 >/dev/null 2>&1 || dpkg -s libglib2.0-0t64 >/dev/null 2>&1 || need+=(libglib2.0-0)
[ ${#need[@]} -eq 0 ] && exit 0
if [ "$(id -u)" != "0" ] || ! command -v apt-get >/dev/null 2>&1; then
  echo "note: system packages ${need[*]} missing (need root + apt): SciPy solver fallback, no viewer screenshots" >&2
  exit 0
fi
echo "installing optional system packages: ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null 2>&1 || true
apt-get install -y -qq "${need[@]}" >/dev/null 2>&1 || echo "note: apt-get install ${need[*]} failed: SciPy solver fallback, no viewer screenshots" >&2
exit 0
