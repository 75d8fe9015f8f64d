#!/usr/bin/env bash
# The README's Grad-CAM++ figure: one sample's `depthsense explain` overlays as a 2 x 6 grid
# (rows: with radar / radar zeroed; columns: 35, 55, 70 m x rgb.layer4, radar branch), tiles
# 400x175, labelled, 256-colour PNG. Needs ImageMagick (`montage`) and the DejaVu fonts.
#
#   scripts/gradcam-figure.sh EXPLAIN_DIR SAMPLE_TOKEN OUT.png [DISTANCES]
set -euo pipefail
dir=${1:?explain output folder}
sample=${2:?sample token (overlay file prefix)}
out=${3:?output PNG}
distances=${4:-35 55 70}
args=()
for state in radar noradar; do
    for d in $distances; do
        for layer in rgb.layer4 radar; do
            name="${layer/radar/radar branch}"
            [ "$state" = radar ] && what="with radar" || what="radar zeroed"
            f="$dir/${sample}_${d}m_${layer}_${state}.png"
            [ -f "$f" ] || { echo "missing $f" >&2; exit 1; }
            args+=(-label "$d m · $name · $what" "$f")
        done
    done
done
ncol=$(( $(wc -w <<<"$distances") * 2 ))
montage "${args[@]}" -tile "${ncol}x2" -geometry 400x175+3+3 -font DejaVu-Sans -pointsize 16 \
    -background white -depth 8 -colors 256 "PNG8:$out"
