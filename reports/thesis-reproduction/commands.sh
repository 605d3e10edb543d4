#!/usr/bin/env bash
# The commands that produced this report (run from the repository root after ./dev.sh setup).
# Budget: the efficient recipe with the thesis's B = 240 for full evaluations, 150 designs
# per ξ (screened on 16 episodes), instead of the thesis's 2000 designs × 240 episodes.
set -euo pipefail
DB=${DB:-sqlite:///runs/thesis.db}
TB=${TB:-.venv/bin/tumblebot}
mkdir -p runs
for xi in 0 1 3 inf; do
    $TB optimize --tasks nav-flat=1 --xi $xi --recipe efficient --trials 150 --batch 240 \
        --storage "$DB" --study nav-flat-xi$xi --seed 0 --workers 2 --quiet
done
$TB report --storage "$DB" --study nav-flat-xi0 --study nav-flat-xi1 --study nav-flat-xi3 --study nav-flat-xiinf \
    -o reports/thesis-reproduction --episodes 240 --workers 2 --seed 1 --quiet
