#!/usr/bin/env bash
# One entry point for a fresh machine: installs what semslam needs (system libraries, a virtual
# environment with the package) the first time, then runs `demo` or `test`.
#   bash dev.sh demo [semslam demo options]    simulate the default tank mission and compare dr/ekf/graph
#   bash dev.sh test [pytest options]          run the test suite
set -euo pipefail
cd "$(dirname "$0")"

VENV=.venv
PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}

# Shared libraries open3d's wheel links against (soname -> Debian package).
SYSTEM_LIBS="libusb-1.0.so.0:libusb-1.0-0 libGL.so.1:libgl1 libEGL.so.1:libegl1 libX11.so.6:libx11-6 libudev.so.1:libudev1 libgomp.so.1:libgomp1"

install_system_libs() {
    local missing=() have
    # Read the cache once: `ldconfig -p | grep -q` fails now and then under pipefail (grep exits at
    # its first match, ldconfig gets SIGPIPE), which made present libraries look missing.
    have=$(ldconfig -p 2>/dev/null || true)
    for pair in $SYSTEM_LIBS; do
        grep -qF "${pair%%:*}" <<<"$have" || missing+=("${pair#*:}")
    done
    "$PYTHON" -c "import ensurepip, venv" 2>/dev/null || missing+=("python3-venv")
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null; then
        echo "dev.sh: missing system packages: ${missing[*]} (install them as root)" >&2
        exit 1
    fi
    echo "dev.sh: installing system packages: ${missing[*]}" >&2
    apt-get -o DPkg::Lock::Timeout=300 update -qq
    DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=300 install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

install_python_env() {
    # Re-install only when pyproject.toml changed since the last install.
    local stamp="$VENV/.installed-$(sha1sum pyproject.toml | cut -c1-12)"
    [ -f "$stamp" ] && return 0
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e '.[test]'
    rm -f "$VENV"/.installed-*
    touch "$stamp"
}

cmd=${1:-}
shift || true
case "$cmd" in
    demo|test) ;;
    *) echo "usage: bash dev.sh demo|test [options]" >&2; exit 2 ;;
esac
install_system_libs
install_python_env
case "$cmd" in
    demo) exec "$VENV/bin/semslam" demo "$@" ;;
    test) exec "$VENV/bin/python" -m pytest "$@" ;;
esac
