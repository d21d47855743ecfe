#!/usr/bin/env bash
# The main job on a fresh machine: set up .venv, then run `emfc-experiment` (the shipped
# identification experiment on the simulated balance, recorded to an MCAP bag, then
# identified) with loopback-only DDS. Arguments go to emfc-experiment (a plan file, -o OUT).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${EMFC_VENV:-$here/.venv}
"$here/tools/setup_env.sh"
# shellcheck source=tools/ros_env.sh
. "$here/tools/ros_env.sh"
cd "$here"
exec "$venv/bin/emfc-experiment" "$@"
