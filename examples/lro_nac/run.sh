#!/usr/bin/env bash
# The LRO NAC left/right pair of ISIS's tests (two line-scan ISDs, 46 points, 92 measures), adjusted with
# jigsaw's settings of its test (observations=yes cksolvedegree=3 camsolve=all twist=no spsolve=none
# radius=no) as far as selfcal's line-scan parameters map them, and side by side with jigsaw's published
# results (compare.py). Writes results/ beside this script (or OUT). DATA (the pair's folder), SELFCAL and PYTHON
# (default: the repository's .venv) may be set.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
data=${DATA:-$root/../shared/data/isis/lro_nac_pair}
selfcal=${SELFCAL:-$root/.venv/bin/selfcal}
python=${PYTHON:-$root/.venv/bin/python}
out=${OUT:-$here/results}
mkdir -p "$out"           # selfcal replaces the folders it wrote before, and only those
start=$SECONDS
# jigsaw's options: RA and DEC of degree 3, no twist, no prior, radii held (radius=no), no rejection (neither
# the robust cleaning nor data snooping)
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_no_twist" --attitude-degree 3 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_no_twist" --out "$out/no_twist" --snoop 0 --robust none --max-iterations 200
# the same with the twist polynomial free as well
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block" --attitude-degree 3 \
    --hold-radii 0.001
$selfcal adjust "$out/block" --out "$out/twist" --snoop 0 --robust none --max-iterations 200
# what the pair determines: bias and drift of RA and DEC (the two Fixed points anchor no higher degree)
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_degree1" --attitude-degree 1 \
    --no-twist --hold-radii 0.001
$selfcal adjust "$out/block_degree1" --out "$out/degree1" --snoop 0 --robust none
# the radii free (no DEM here): degree 1 adjusts; degree 3 is singular and the engine names the coefficients
$selfcal import isis "$data/observationPair.net" --images "$data" --out "$out/block_radii_free" --attitude-degree 1 \
    --no-twist
$selfcal adjust "$out/block_radii_free" --out "$out/radii_free" --snoop 0 --robust none
echo "four imports and four adjustments with reports in $((SECONDS - start)) s" >&2
$python "$here/compare.py" "$out" "$data/../EXPECTED_VALUES.txt"
