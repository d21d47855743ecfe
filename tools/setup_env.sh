#!/usr/bin/env bash
# Create or refresh the virtual environment .venv (or $EMFC_VENV) with emfc_ros installed
# the way a user installs it (`pip install .`, pulling the ROS 2 Jazzy wheels from PyPI),
# plus what the tests and benchmarks need. Safe to run again: dependencies are installed
# once per change of setup.py or of this script, the package itself once per change of its
# sources (a hash of every installed file: emfc_ros/, config/, launch/, lib_wrappers/,
# resource/, setup.py, setup.cfg, package.xml), followed by emfc-compile-kernels (numba's
# cache). A current venv costs well under a second and prints nothing. `setup_env.sh --check` changes nothing: exit 0 when the venv is
# current, 1 (saying what is stale) when this script would install something.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv=${EMFC_VENV:-$here/.venv}
check=0
if [ "${1:-}" = --check ]; then
  check=1
fi

py=${PYTHON:-}
if [ -z "$py" ]; then
  for candidate in python3.11 python3; do
    if command -v "$candidate" >/dev/null 2>&1 &&
       "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      py=$candidate
      break
    fi
  done
fi
if [ -z "$py" ]; then
  echo "setup_env: Python 3.11 is required (the ROS 2 Jazzy wheels exist for CPython 3.11 only)" >&2
  exit 1
fi

# The tests run in a private network namespace when root: that needs `ip` (iproute2).
if [ "$(id -u)" = 0 ] && ! command -v ip >/dev/null 2>&1 && command -v apt-get >/dev/null; then
  echo "setup_env: installing iproute2 for the private network namespace" >&2
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq iproute2 >/dev/null
fi

# pip here warns about every configured local index folder that does not exist: hide those
# lines only, keep everything else (errors included).
quiet_pip() { grep -v 'is ignored: it is neither a file nor a directory' || true; }

deps_stamp="$venv/.emfc-deps-$(cat "$here/setup.py" "$here/tools/setup_env.sh" | sha256sum | cut -c1-16)"
package_hash() {
  # contents, names and modes of every file the package installs
  local sources=(emfc_ros config launch lib_wrappers resource setup.py setup.cfg package.xml)
  (cd "$here" &&
   find "${sources[@]}" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' -print0 |
     LC_ALL=C sort -z | xargs -0 sha256sum &&
   find "${sources[@]}" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' -printf '%m %p\n' |
     LC_ALL=C sort) | sha256sum | cut -c1-16
}
package_stamp="$venv/.emfc-package-$(package_hash)"
# The test tools the dependencies bring (flake8 for test/test_flake8.py, mypy for
# test/test_types.py): one gone from the venv reinstalls the dependencies.
tools_missing() {
  local tool
  for tool in flake8 mypy; do
    [ -x "$venv/bin/$tool" ] || { echo "$tool"; return 0; }
  done
  return 1
}
if [ "$check" = 1 ]; then
  stale=()
  [ -x "$venv/bin/python" ] || stale+=("no virtual environment at $venv")
  [ -f "$deps_stamp" ] || stale+=("dependencies not installed for this setup.py")
  if missing_tool=$(tools_missing); then
    stale+=("$missing_tool (a test tool) not installed")
  fi
  [ -f "$package_stamp" ] && [ -x "$venv/bin/emfc-experiment" ] ||
    stale+=("emfc_ros not installed from the current sources")
  if [ -x "$here/../shared/ros2-jazzy-cli/install.sh" ] && ! ls "$venv"/.emfc-ros2cli-* >/dev/null 2>&1; then
    stale+=("the real ROS 2 command line (../shared/ros2-jazzy-cli) not installed")
  fi
  if [ ${#stale[@]} -gt 0 ]; then
    printf 'setup_env --check: %s\n' "${stale[@]}" >&2
    exit 1
  fi
  exit 0
fi

if [ ! -x "$venv/bin/python" ]; then
  echo "setup_env: creating $venv" >&2
  "$py" -m venv "$venv"
fi
if [ ! -f "$deps_stamp" ] || tools_missing >/dev/null; then
  echo "setup_env: installing dependencies into $venv (first run takes a few minutes)" >&2
  # colcon needs setuptools<80 (design brief section 2).
  "$venv/bin/python" -m pip install -q 'setuptools<80' wheel 2>&1 | quiet_pip
  "$venv/bin/python" -m pip install -q "$here[plot,test,daqmx]" \
    'colcon-common-extensions' 'flake8>=6' 'flake8-quotes' 'flake8-import-order' \
    'flake8-docstrings' 'pep8-naming' 'mypy==2.4.*' 'types-PyYAML' 2>&1 | quiet_pip
  rm -f "$venv"/.emfc-deps-* "$venv"/.emfc-package-*
  touch "$deps_stamp"
fi
# The real ROS 2 Jazzy command line (ros2 launch, run, service, topic, param) and the launch
# packages, for the launch tests, when ../shared/ros2-jazzy-cli is there (CI has it; it is
# never copied into this repository). Without it the tests use their stand-in and say so.
cli=$here/../shared/ros2-jazzy-cli
if [ -x "$cli/install.sh" ]; then
  cli_stamp="$venv/.emfc-ros2cli-$( (cat "$cli/install.sh"; ls -R "$cli/src" 2>/dev/null) | sha256sum | cut -c1-16)"
  if [ "$check" = 0 ] && [ ! -f "$cli_stamp" ]; then
    echo "setup_env: installing the real ROS 2 command line from $cli (for the launch tests)" >&2
    "$cli/install.sh" "$venv" >&2
    rm -f "$venv"/.emfc-ros2cli-*
    touch "$cli_stamp"
  fi
fi
# The package itself, non-editable so that its data files land in $venv/share and
# $venv/lib/emfc_ros as `pip install .` puts them for users; again only when its sources
# changed (or the install is gone).
if [ ! -f "$package_stamp" ] || [ ! -x "$venv/bin/emfc-experiment" ]; then
  echo "setup_env: installing emfc_ros into $venv" >&2
  rm -f "$venv"/.emfc-package-*
  "$venv/bin/python" -m pip install -q --no-deps --no-build-isolation --force-reinstall \
    "$here" 2>&1 | quiet_pip
  # numba's kernels into its cache now, not in the first run (the simulator's takes about
  # 15 s; unchanged sources keep their cache across reinstalls, numba keys it by content)
  echo "setup_env: compiling the numba kernels (emfc-compile-kernels)" >&2
  "$venv/bin/emfc-compile-kernels" >&2
  touch "$package_stamp"
fi
