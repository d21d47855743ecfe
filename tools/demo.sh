#!/usr/bin/env bash
# The main job on the simulated balance (sets up .venv first). Arguments go to emfc-demo.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${EMFC_VENV:-$here/.venv}
"$here/tools/setup_env.sh"
# shellcheck source=tools/ros_env.sh
. "$here/tools/ros_env.sh"
cd "$here"
exec "$venv/bin/emfc-demo" "$@"
