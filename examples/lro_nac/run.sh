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
# jigsaw's options read literally: attitude of degree 3, no twist, no prior, radii held (radius=no), no rejection
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_no_yaw" --attitude-degree 3 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_no_yaw" --out "$out/no_yaw" --snoop 0 --max-iterations 200
# the same with the yaw polynomial free: jigsaw's RA turns about J2000 Z, 105 deg from the NAC's line of sight,
# so its two angles reach a rotation about the line of sight that roll and pitch alone do not (README.md)
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block" --attitude-degree 3 \
    --hold-radii 0.001
$selfcal adjust "$out/block" --out "$out/yaw" --snoop 0 --max-iterations 200
# what the pair determines: bias and drift of roll and pitch (the two Fixed points anchor no higher degree)
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_degree1" --attitude-degree 1 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_degree1" --out "$out/degree1" --snoop 0
end=$(date +%s.%N)
echo "three imports and three adjustments with reports in $(echo "$end - $start" | bc) s" >&2
$python "$here/compare.py" "$out"
