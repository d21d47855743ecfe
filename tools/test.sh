#!/usr/bin/env bash
# Run the test suite on a fresh machine: set up .venv, then pytest with loopback-only DDS,
# inside a private network namespace when root. Extra arguments go to pytest.
# EMFC_TEST_TIMEOUT_SCALE=F (default 1, positive) multiplies every test timeout (slow machines).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${EMFC_VENV:-$here/.venv}
"$here/tools/setup_env.sh"
# shellcheck source=tools/ros_env.sh
. "$here/tools/ros_env.sh"
cd "$here"
cmd=("$venv/bin/pytest" -q -p no:cacheprovider "$@")
if [ "$(id -u)" = 0 ] && [ -z "${EMFC_IN_NETNS:-}" ] && command -v unshare >/dev/null; then
  # EMFC_TEST_WORKERS=N (default 2) parallel pytest-xdist workers, a file per worker at a
  # time, each in a network namespace of its own (test/ros_harness.py); 1 runs serially.
  workers=${EMFC_TEST_WORKERS:-2}
  if [ "$workers" -gt 1 ] 2>/dev/null; then
    cmd+=(-n "$workers" --dist loadfile)
  fi
  echo "test: running in a private network namespace (loopback only), ROS_DOMAIN_ID=$ROS_DOMAIN_ID, ${workers} worker(s)" >&2
  exec unshare -n -- env EMFC_IN_NETNS=1 bash -c 'ip link set lo up && exec "$@"' _ "${cmd[@]}"
fi
echo "test: not root; loopback-only discovery, ROS_DOMAIN_ID=$ROS_DOMAIN_ID" >&2
exec "${cmd[@]}"
