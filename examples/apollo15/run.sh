#!/usr/bin/env bash
# The Apollo 15 Metric network of ISIS's tests (7 frames, 395 points, 969 measures), adjusted with jigsaw's
# settings and side by side with jigsaw's published results (compare.py), then with selfcal's own tests.
# Writes results/ beside this script (or OUT). DATA (the network's folder), SELFCAL and PYTHON (default: the
# repository's .venv) may be set.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
data=${DATA:-$root/../shared/data/isis/apollo15_metric}
selfcal=${SELFCAL:-$root/.venv/bin/selfcal}
python=${PYTHON:-$root/.venv/bin/python}
out=${OUT:-$here/results}
mkdir -p "$out"           # selfcal replaces the folders it wrote before, and only those
start=$SECONDS
# jigsaw: spsolve=position (sigma 1000 m), camsolve=angles with twist (sigma 2 deg), radius free, no rejection
# (neither the robust cleaning nor data snooping: jigsaw keeps every measure)
$selfcal import isis "$data/apolloNet.pvl" --images "$data" --out "$out/block" --sigma-position-m 1000 \
    --sigma-attitude-deg 2
$selfcal adjust "$out/block" --out "$out/jigsaw" --snoop 0 --robust none
# selfcal's own tests on the same network
$selfcal adjust "$out/block" --out "$out/snooped" --snoop 3.0
$selfcal adjust "$out/block" --out "$out/variance" --snoop 3.0 --variance-components
# self-calibration of the Metric camera: principal distance and point weighted loosely (1 mm, 0.1 mm) instead
# of held at the mission's calibration, Brown's APs, screened
rm -rf "$out/block_selfcal" && cp -r "$out/block" "$out/block_selfcal"
sed -e 's/^sigma_focal_mm = .*/sigma_focal_mm = 1.0/' -e 's/^sigma_x0_mm = .*/sigma_x0_mm = 0.1/' \
    -e 's/^sigma_y0_mm = .*/sigma_y0_mm = 0.1/' "$out/block/block.toml" > "$out/block_selfcal/block.toml"
$selfcal adjust "$out/block_selfcal" --out "$out/selfcal" --snoop 3.0 --ap brown --screen
echo "import and four adjustments with reports in $((SECONDS - start)) s" >&2
$python "$here/compare.py" "$out" "$data/../EXPECTED_VALUES.txt"
