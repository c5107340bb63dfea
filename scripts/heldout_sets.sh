#!/usr/bin/env bash
# Builds the held-out evaluation sets (no training target comes from them) and the training
# and validation targets of expert iteration, with contact sheets.
#   script glyphs: URW Z003 Medium Italic (Debian fonts-urw-base35), thin (8% of pixels)
#   silhouettes:   Openclipart's public-domain animal clip art (Debian openclipart-svg),
#                  rasterized with rsvg-convert (librsvg2-bin), opaque pixels
# Usage: bash scripts/heldout_sets.sh [WORKDIR]   (needs: apt-get install -y fonts-urw-base35
#        openclipart-svg librsvg2-bin)
set -euo pipefail
W=${1:-work}
ngpmc targets build glyphs -o "$W/heldout/z003_all" \
    --font /usr/share/fonts/opentype/urw-base35/Z003-MediumItalic.otf
ngpmc targets build clipart -o "$W/heldout/sil_all"      # /usr/share/openclipart/svg/animals
ngpmc targets build varied -o "$W/data/varied" --count 300 --mirror
ngpmc targets build scribbles -o "$W/data/scribbles" --count 300 --mirror
ngpmc targets build varied -o "$W/data/val_varied" --count 12 --seed 1
ngpmc targets build glyphs -o "$W/data/val_glyphs"         # DejaVu Sans Bold (validation)
ngpmc targets show "$W/heldout/z003_all" -o "$W/heldout/z003.png" --max 48 --cols 12
ngpmc targets show "$W/heldout/sil_all" -o "$W/heldout/sil.png" --max 48 --cols 12
ngpmc targets show "$W/data/varied" -o "$W/data/varied.png" --max 48 --cols 12
