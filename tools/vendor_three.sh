#!/usr/bin/env bash
# Rebuild the vendored three.js of the 3D view (c3f_slam/view/vendor/three.view.min.js) from the npm registry:
# three.js's own sources, the classes the viewer uses and OrbitControls, bundled and minified by esbuild into
# one classic script that defines the global THREE (so it can be inlined into a self-contained HTML file).
#   tools/vendor_three.sh [THREE_VERSION] [ESBUILD_VERSION]      (needs node and npm)
set -euo pipefail
three=${1:-0.187.0}
esbuild=${2:-0.25.12}
dest=$(cd "$(dirname "$0")/.." && pwd)/c3f_slam/view/vendor
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
npm init -y >/dev/null
npm install --silent --no-audit --no-fund "three@$three" "esbuild@$esbuild"
cat > entry.js <<'JS'
export {
  WebGLRenderer, Scene, PerspectiveCamera, Group, Color, Vector3, Box3, Sphere, Plane, DoubleSide,
  BufferGeometry, BufferAttribute, Float32BufferAttribute,
  Mesh, MeshLambertMaterial, MeshBasicMaterial, Line, LineSegments, LineBasicMaterial, Points, PointsMaterial,
  AmbientLight, DirectionalLight
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
JS
{
    echo "/* three.js $three (https://threejs.org, MIT licence: LICENSE beside this file): the classes the C3Fusion"
    echo "   view uses and OrbitControls, bundled by esbuild $esbuild (tools/vendor_three.sh) as the global THREE. */"
    node_modules/.bin/esbuild entry.js --bundle --minify --format=iife --global-name=THREE --legal-comments=none \
        --target=es2020 --log-level=warning
} > "$dest/three.view.min.js"
cp node_modules/three/LICENSE "$dest/LICENSE"
echo "wrote $dest/three.view.min.js ($(wc -c < "$dest/three.view.min.js") bytes), three $three"
