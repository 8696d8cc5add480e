#!/bin/sh
# Pleiades stereo over Mont Ventoux (../shared/data/pushbroom/pleiades/phr_ventoux, CNES shareloc, Apache-2.0):
# SIFT tie points between the two crops, a tie-only rpc block, adjusted three times:
#   uncorrected  the vendor RPCs as they are (bias = "none", no snooping)
#   shift        a shift bias per image, sigma_bias_px = 10 (the datum of the tie-only block), snooping on
#   affine       the affine bias, the same prior
# and exports the left image's bias-corrected RPCs for GDAL (shift: exact; affine: refitted, misfit printed).
# Run from the repository root: sh examples/ventoux/run.sh [OUT]   (about 20 s on 2 cores)
set -e
OUT=${1:-examples/ventoux/results}
SELFCAL=${SELFCAL:-.venv/bin/selfcal}
PY=${PY:-.venv/bin/python}
MAKE=examples/ventoux/make_block.py
$PY $MAKE "$OUT/block-uncorrected" --bias none
$PY $MAKE "$OUT/block-shift" --bias shift --sigma-bias-px 10
$PY $MAKE "$OUT/block-affine" --bias affine --sigma-bias-px 10
$SELFCAL adjust "$OUT/block-uncorrected" --snoop 0 --out "$OUT/uncorrected"
$SELFCAL adjust "$OUT/block-shift" --out "$OUT/shift"
$SELFCAL adjust "$OUT/block-affine" --out "$OUT/affine"
$SELFCAL export rpc "$OUT/shift" --block "$OUT/block-shift" --image left --out "$OUT/left_shift.RPB"
$SELFCAL export rpc "$OUT/affine" --block "$OUT/block-affine" --image left --out "$OUT/left_affine_RPC.TXT"
$PY examples/ventoux/summary.py "$OUT" uncorrected shift affine
