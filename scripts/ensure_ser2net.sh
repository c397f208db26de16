#!/usr/bin/env bash
# Make sure ser2net (a serial-port server with RFC 2217, Debian package `ser2net`) is present: the
# `rfc2217://` link is tested against it (tests/test_remote_link.py). Idempotent and non-interactive:
# does nothing when ser2net is found; otherwise runs `apt-get update` once and installs it.
# Exit status: 0 when ser2net is available afterwards, 1 otherwise (with the reason on stderr; the tests
# that need it are then skipped with that reason). UWB_NO_INSTALL=1 only checks.
set -euo pipefail

if command -v ser2net >/dev/null 2>&1; then
    echo "ensure_ser2net: $(ser2net -v 2>&1 | head -1) present"
    exit 0
fi
if [ "${UWB_NO_INSTALL:-0}" = "1" ]; then
    echo "ensure_ser2net: ser2net missing (UWB_NO_INSTALL=1, not installing)" >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO="sudo -n env DEBIAN_FRONTEND=noninteractive"  # sudo drops the environment
    else
        echo "ensure_ser2net: ser2net missing; not root and no passwordless sudo." >&2
        echo "  install it with: apt-get install --no-install-recommends ser2net" >&2
        exit 1
    fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure_ser2net: ser2net missing and apt-get is not available" >&2
    exit 1
fi
echo "ensure_ser2net: installing ser2net"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q >/dev/null
$SUDO apt-get install -y -q --no-install-recommends ser2net >/dev/null
if ! command -v ser2net >/dev/null 2>&1; then
    echo "ensure_ser2net: ser2net still missing after apt-get install" >&2
    exit 1
fi
echo "ensure_ser2net: done ($(ser2net -v 2>&1 | head -1))"
