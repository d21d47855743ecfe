#!/usr/bin/env bash
# Run one benchmark from bench/ (name without .py) with loopback-only DDS, in a private
# network namespace when root. Extra arguments go to the benchmark.
#   tools/bench.sh bench_signals
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${EMFC_VENV:-$here/.venv}
name=${1:?usage: tools/bench.sh BENCH_NAME [ARGS...]}
shift
"$here/tools/setup_env.sh"
# shellcheck source=tools/ros_env.sh
. "$here/tools/ros_env.sh"
cd "$here"
cmd=("$venv/bin/python" "bench/$name.py" "$@")
if [ "$(id -u)" = 0 ] && [ -z "${EMFC_IN_NETNS:-}" ] && command -v unshare >/dev/null; then
  exec unshare -n -- env EMFC_IN_NETNS=1 bash -c 'ip link set lo up && exec "$@"' _ "${cmd[@]}"
fi
exec "${cmd[@]}"
