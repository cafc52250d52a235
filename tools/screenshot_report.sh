#!/usr/bin/env bash
# Render a demo report (or any HTML file) with headless Chromium to a full-page PNG, offline.
#   tools/screenshot_report.sh demo_out/report.html report.png [WIDTH] [HEIGHT]
# Installs Debian's chromium (apt-get) when no chromium is on PATH.
set -euo pipefail
html=${1:?usage: $0 REPORT.html OUT.png [WIDTH] [HEIGHT]}
out=${2:?usage: $0 REPORT.html OUT.png [WIDTH] [HEIGHT]}
width=${3:-1200}
height=${4:-6000}
[ -f "$html" ] || { echo "error: $html: file not found" >&2; exit 2; }
browser=$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)
if [ -z "$browser" ]; then
    apt-get update -qq && apt-get install -y -qq chromium >/dev/null
    browser=$(command -v chromium)
fi
profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT
"$browser" --headless --no-sandbox --disable-gpu --hide-scrollbars --user-data-dir="$profile" \
    --window-size="$width,$height" --screenshot="$(realpath -m "$out")" "file://$(realpath "$html")" 2>/dev/null
echo "wrote $out"
