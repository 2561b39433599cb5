#!/bin/bash
# The object-space matching on a block of about 10 800 × 10 800 groundels (issue 19's goal:
# a 10 000 × 10 000-groundel block in patches within 4 GB). Renders the scene (about 20 min
# on 2 cores), makes a coarse model 3 px of parallax off (the truth averaged over 50 m cells,
# spline-resampled to 10 m; needs gdalwarp) and runs the OSLSM under /usr/bin/time -v (peak
# memory in "Maximum resident set size"). Usage: benches/oslsm_10k.sh RIG DIR
set -euo pipefail
rig=${1:?usage: oslsm_10k.sh RIG DIR}
dir=${2:?usage: oslsm_10k.sh RIG DIR}
"$rig" sim scene --out "$dir" --area=-4,-50,96,50 --resolution-um 8 --gains 1,1.2 \
    --offsets 0,-3000 --noise-dn 150
cd "$dir"
ext=$(gdalinfo truth-dem.tif | awk '/Upper Left/{gsub(/[(),]/," ");ulx=$3;uly=$4} /Lower Right/{gsub(/[(),]/," ");lrx=$3;lry=$4} END{print ulx, lry, lrx, uly}')
gdalwarp -q -overwrite -tr 50 50 -r average truth-dem.tif c50.tif
# shellcheck disable=SC2086
gdalwarp -q -overwrite -te $ext -tr 10 10 -r cubicspline c50.tif cc50.tif
sed -i 's/^method = "sweep".*/method = "oslsm"/; s/^\[check\]/[matching.oslsm]\ncoarse = "cc50.tif"\n\n[check]/' block.toml
/usr/bin/time -v "$rig" dtm block.toml --out out
