#!/usr/bin/env bash
# The commands behind reports/servo-ablation (run from the repository root after ./dev.sh setup).
# Budget: per servo, one nav-flat ξ = 0 study with goto (no training needed under any servo):
# the standard recipe, 60 designs × 48 episodes (2 880 episodes), then 240 fresh episodes per cell.
set -euo pipefail
DB=${DB:-sqlite:///runs/servo.db}
TB=${TB:-.venv/bin/tumblebot}
W=${WORKERS:-2}
mkdir -p runs
$TB optimize --tasks nav-flat --xi 0 --gait goto --trials 60 --batch 48 --startup 20 \
    --storage "$DB" --study servo-dc-xi0 --seed 0 --workers "$W" --quiet
$TB optimize --tasks nav-flat --xi 0 --gait goto --motor-model velocity --stall-torque 10 --trials 60 --batch 48 \
    --startup 20 --storage "$DB" --study servo-strong-xi0 --seed 0 --workers "$W" --quiet
.venv/bin/python reports/servo-ablation/ablation.py --episodes 240 --workers "$W" --studies "$DB"
# The bar of the servo issue, as a user types it:
$TB evaluate --task nav-flat --design 0.293,0.117,0.158,0.218 --gait goto --motor-model velocity --stall-torque 10 \
    --episodes 48 --seed 0 --json
$TB evaluate --task nav-flat --design 0.293,0.117,0.158,0.218 --gait goto --episodes 48 --seed 0 --json
