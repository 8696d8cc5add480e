#!/bin/sh
# The Coal Oil Point Reserve block (../shared/data/copr, CC BY-SA 4.0): import COLMAP's reconstruction
# georeferenced by a similarity from the ODM targets, every target a check point (the targets lie on one
# line along the beach: they cannot fix the block's roll about it, so the block is a free network in the
# import's frame), adjust it with four AP models (data snooping on, APs screened), write the reports, say
# what the control can and cannot fix (control.py), and export the wavelet:db4 result as a COLMAP dense
# workspace (the two images of the data) checked with pycolmap.
# Run: sh examples/copr/run.sh [OUT]   (about 7 minutes on 2 busy cores; OUT defaults to copr-results/ in the
# current folder). DATA (the block's folder), SELFCAL and PYTHON (default: the repository's .venv) may be set.
set -e
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
DATA=${DATA:-$ROOT/../shared/data/copr}
OUT=${1:-copr-results}
SELFCAL=${SELFCAL:-$ROOT/.venv/bin/selfcal}
PY=${PYTHON:-$ROOT/.venv/bin/python}
mkdir -p "$OUT"
# Canon EOS 450D: 22.2 mm x 14.8 mm sensor, 4272 px across -> 5.2 um pixels; hand-held GPS: 3 m / 5 m
$SELFCAL import colmap "$DATA/sparse" --gcp "$DATA/gcp_list.txt" --pixel-size-mm 0.0052 \
    --check gcp00,gcp01,gcp02,gcp03,gcp04,gcp05,gcp06,gcp07,gcp08,gcp09 \
    --gcp-sigma-xy 3 --gcp-sigma-z 5 --out "$OUT/block"
for AP in none brown legendre wavelet:db4; do
    NAME=$(echo "$AP" | tr ':' '-')
    $SELFCAL adjust "$OUT/block" --ap "$AP" --screen --out "$OUT/$NAME"
done
$PY $HERE/summary.py "$OUT" none brown legendre wavelet-db4
$PY $HERE/control.py "$OUT/brown"
$PY $HERE/control.py "$OUT/brown" --sigma-z 0.1
$SELFCAL export colmap-workspace "$OUT/wavelet-db4" --images "$DATA/images" --out "$OUT/workspace-db4"
$PY $HERE/check_workspace.py "$OUT/wavelet-db4" "$OUT/workspace-db4"
