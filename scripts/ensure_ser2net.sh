#!/usr/bin/env bash
# Make sure ser2net (a serial-port server with RFC 2217, Debian package `ser2net`) is present: the
# `rfc2217://` link is tested against it (tests/device/test_remote_link.py). Idempotent and non-interactive:
# does nothing when ser2net is found; otherwise runs `apt-get update` once and installs it.
# Exit status: 0 when ser2net is available afterwards, 1 otherwise (with the reason on stderr; the tests
# that need it are then skipped with that reason). UWB_NO_INSTALL=1 only checks.
set -euo pipefail

if command -v ser2net >/dev/null 2>&1; then
    echo "ensure_ser2net: $(ser2net -v 2>&1 | head -1) present"
    exit 0
fi
# shellcheck source=apt_install.sh
. "$(dirname "$0")/apt_install.sh"
apt_ready ensure_ser2net ser2net
apt_get_install ser2net
if ! command -v ser2net >/dev/null 2>&1; then
    echo "ensure_ser2net: ser2net still missing after apt-get install" >&2
    exit 1
fi
echo "ensure_ser2net: done ($(ser2net -v 2>&1 | head -1))"
