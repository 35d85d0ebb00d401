#!/usr/bin/env bash
# Optional system libraries for speed: SuiteSparse (CHOLMOD, for the sparse Cholesky
# solver) and OpenBLAS. tryon works without them (it falls back to SciPy's SuperLU), so a
# machine where apt is unavailable or we are not root just skips this step.
set -u
need=()
dpkg -s libsuitesparse-dev >/dev/null 2>&1 || need+=(libsuitesparse-dev)
dpkg -s libopenblas0-pthread >/dev/null 2>&1 || need+=(libopenblas0-pthread)
[ ${#need[@]} -eq 0 ] && exit 0
if [ "$(id -u)" != "0" ] || ! command -v apt-get >/dev/null 2>&1; then
  echo "note: optional system packages ${need[*]} missing (need root + apt); using the SciPy solver fallback" >&2
  exit 0
fi
echo "installing optional system packages: ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null 2>&1 || true
apt-get install -y -qq "${need[@]}" >/dev/null 2>&1 || echo "note: apt-get install ${need[*]} failed; using the SciPy solver fallback" >&2
exit 0
