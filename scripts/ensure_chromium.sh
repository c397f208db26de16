#!/usr/bin/env bash
# Make sure Chromium (Debian package `chromium`) is present: the campaign report is opened in it headless
# (tests/campaign/test_report_browser.py: no console error, every figure decodes and is visible, the
# screenshot is not blank). Idempotent and non-interactive: does nothing when chromium is found; otherwise
# runs `apt-get update` once and installs it. Exit status: 0 when chromium is available afterwards, 1
# otherwise (the reason on stderr; the browser test then skips with it). UWB_NO_INSTALL=1 only checks.
set -euo pipefail

if command -v chromium >/dev/null 2>&1; then
    echo "ensure_chromium: $(chromium --version 2>/dev/null | head -1) present"
    exit 0
fi
# shellcheck source=apt_install.sh
. "$(dirname "$0")/apt_install.sh"
apt_ready ensure_chromium chromium
apt_get_install chromium
if ! command -v chromium >/dev/null 2>&1; then
    echo "ensure_chromium: chromium still missing after apt-get install" >&2
    exit 1
fi
echo "ensure_chromium: done ($(chromium --version 2>/dev/null | head -1))"
