#!/usr/bin/env bash
# Make docs/images/foxglove-trial.png: run one real trial through the digital twin (the
# deployed host, Pi agent and firmware, with the simulator as the world), open its log in
# Foxglove Studio with docs/foxglove-layout.json, and screenshot it at 60 % of the trial.
# Needs the project's .venv (./dev.sh setup), Node.js with npm, and Debian's chromium
# (installed here when run as root). Takes about two minutes.
set -euo pipefail
cd "$(dirname "$0")"
root=$(cd ../.. && pwd)
if [ ! -x /usr/bin/chromium ]; then
    if [ "$(id -u)" = 0 ]; then
        apt-get update -q && apt-get install -y -q chromium
    else
        echo "make.sh: needs Debian's chromium: sudo apt-get install chromium" >&2
        exit 1
    fi
fi
npm ci --no-audit --no-fund --silent
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$root/.venv/bin/tumblebot" twin run --out "$work/twin" --points 1 --per-point 1
log="$work/twin/trial-0000.mcap"
at=$("$root/.venv/bin/python" - "$log" <<'PY'
import datetime, sys
from mcap.reader import make_reader
with open(sys.argv[1], "rb") as fh:
    stats = make_reader(fh).get_summary().statistics
ns = stats.message_start_time + int(0.6 * (stats.message_end_time - stats.message_start_time))
print(datetime.datetime.fromtimestamp(ns / 1e9, datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ"))
PY
)
mkdir -p ../images
SHOT_TIME="$at" node shoot.mjs "$log" ../images/foxglove-trial.png
