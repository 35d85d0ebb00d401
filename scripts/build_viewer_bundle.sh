#!/usr/bin/env bash
# Rebuild the vendored three.js bundle of the web viewer (src/tryon/viewer/static/
# three-bundle.min.js: three.js r187 with OrbitControls, tree-shaken to what the viewer
# uses, MIT licence in LICENSE-three.txt). Needs node and npm; run from the repository root.
set -euo pipefail
root=$(pwd)
work=$(mktemp -d)
cp scripts/viewer_bundle_entry.js "$work/entry.js"
cd "$work"
npm init -y >/dev/null
npm install --silent three@0.187.0 esbuild@0.25
npx esbuild entry.js --bundle --minify --format=esm --legal-comments=inline --outfile="$root/src/tryon/viewer/static/three-bundle.min.js"
cp node_modules/three/LICENSE "$root/src/tryon/viewer/static/LICENSE-three.txt"
rm -rf "$work"
