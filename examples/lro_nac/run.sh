#!/usr/bin/env bash
# The LRO NAC left/right pair of ISIS's tests (two line-scan ISDs, 46 points, 92 measures), adjusted with
# jigsaw's settings of its test (observations=yes cksolvedegree=3 camsolve=all twist=no spsolve=none
# radius=no) as far as selfcal's line-scan parameters map them, and side by side with jigsaw's published
# results (compare.py). Writes results/ beside this script. SELFCAL (default: selfcal) and DATA may be set.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
data=${DATA:-$here/../../../shared/data/isis/lro_nac_pair}
selfcal=${SELFCAL:-selfcal}
python=${PYTHON:-python3}
out=$here/results
rm -rf "$out"
mkdir -p "$out"
start=$(date +%s.%N)
# jigsaw's options: RA and DEC of degree 3, no twist, no prior, radii held (radius=no), no rejection
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_no_twist" --attitude-degree 3 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_no_twist" --out "$out/no_twist" --snoop 0 --max-iterations 200
# the same with the twist polynomial free as well
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block" --attitude-degree 3 \
    --hold-radii 0.001
$selfcal adjust "$out/block" --out "$out/twist" --snoop 0 --max-iterations 200
# what the pair determines: bias and drift of RA and DEC (the two Fixed points anchor no higher degree)
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_degree1" --attitude-degree 1 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_degree1" --out "$out/degree1" --snoop 0
# the radii free (no DEM here): degree 1 adjusts; degree 3 is singular and the engine names the coefficients
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_radii_free" --attitude-degree 1 \
    --no-twist
$selfcal adjust "$out/block_radii_free" --out "$out/radii_free" --snoop 0
end=$(date +%s.%N)
echo "four imports and four adjustments with reports in $(echo "$end - $start" | bc) s" >&2
$python "$here/compare.py" "$out"
