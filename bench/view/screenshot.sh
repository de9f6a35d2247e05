#!/usr/bin/env bash
# The live view's picture for the README: a `--view-save` recording of 7-Scenes opened in the
# Rerun web viewer (`rerun --web-viewer`, from PyPI rerun-sdk==0.36.3, the SDK's version),
# rendered by headless Chromium (Debian's chromium, driven by playwright-core from npm), the
# console's errors printed (the script fails on any), the screenshot written.
#   bench/view/screenshot.sh DWSLAM_BIN OUT.png [FRAMES]
# Needs: python3 -m pip install rerun-sdk==0.36.3; apt-get install chromium; npm install
# playwright-core (in bench/view or above).
set -euo pipefail
bin=$1 out=$2 frames=${3:-1000}
here=$(cd "$(dirname "$0")" && pwd)
data=${DWSLAM_DATA:-$here/../../../shared/data}
work=$(mktemp -d)
# The viewer runs in a session of its own: its launcher starts the viewer binary as a child,
# and the whole group goes at the end.
trap 'kill -- -$viewer 2>/dev/null || true; rm -rf "$work"' EXIT
"$bin" run "$data/seven_scenes_redkitchen_1000" --max-frames "$frames" --deterministic --quiet \
  --view-save "$work/view.rrd" --out "$work/run" > /dev/null
# The layout (the 3D map large, the image and the time series beside it) merged in.
python3 "$here/blueprint.py" "$work/dwslam.rbl" > /dev/null
rerun rrd merge "$work/view.rrd" "$work/dwslam.rbl" -o "$work/with-layout.rrd"
setsid rerun --web-viewer --renderer webgl --port 9876 --web-viewer-port 9090 "$work/with-layout.rrd" \
  > "$work/viewer.log" 2>&1 &
viewer=$!
sleep 5
node "${SCREENSHOT_MJS:-$here/screenshot.mjs}" "http://127.0.0.1:9090/?url=rerun%2Bhttp://127.0.0.1:9876/proxy" "$out"
