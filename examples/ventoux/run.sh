#!/bin/sh
# Pleiades stereo over Mont Ventoux (../shared/data/pushbroom/pleiades/phr_ventoux, CNES shareloc, Apache-2.0):
# SIFT tie points between the two crops, a tie-only rpc block, adjusted three times:
#   uncorrected  the vendor RPCs as they are (bias = "none", no rejection: neither robust cleaning nor snooping)
#   shift        a shift bias per image, sigma_bias_px = 10 (the datum of the tie-only block), snooping on
#   affine       the affine bias, the same prior
# and exports the left image's bias-corrected RPCs for GDAL (shift: exact; affine: refitted, misfit printed).
# Run: sh examples/ventoux/run.sh [OUT]   (about 20 s on 2 cores; OUT defaults to results/ beside this script).
# DATA (the crops' folder), SELFCAL and PYTHON (default: the repository's .venv) may be set.
set -e
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
OUT=${1:-$HERE/results}
DATA=${DATA:-$ROOT/../shared/data/pushbroom/pleiades/phr_ventoux}
SELFCAL=${SELFCAL:-$ROOT/.venv/bin/selfcal}
PYTHON=${PYTHON:-$ROOT/.venv/bin/python}
MAKE=$HERE/make_block.py
"$PYTHON" "$MAKE" "$OUT/block-uncorrected" --bias none --data "$DATA"
"$PYTHON" "$MAKE" "$OUT/block-shift" --bias shift --sigma-bias-px 10 --data "$DATA"
"$PYTHON" "$MAKE" "$OUT/block-affine" --bias affine --sigma-bias-px 10 --data "$DATA"
$SELFCAL adjust "$OUT/block-uncorrected" --snoop 0 --robust none --out "$OUT/uncorrected"
$SELFCAL adjust "$OUT/block-shift" --out "$OUT/shift"
$SELFCAL adjust "$OUT/block-affine" --out "$OUT/affine"
$SELFCAL export rpc "$OUT/shift" --block "$OUT/block-shift" --image left --out "$OUT/left_shift.RPB"
$SELFCAL export rpc "$OUT/affine" --block "$OUT/block-affine" --image left --out "$OUT/left_affine_RPC.TXT"
"$PYTHON" "$HERE/summary.py" "$OUT" uncorrected shift affine
