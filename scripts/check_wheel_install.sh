#!/usr/bin/env bash
# A package that installs anywhere: build the wheel, install it (not editable) into a fresh virtualenv OUTSIDE
# the checkout, and from a directory outside it run `uwb-hil --version`, `uwb-hil run --duration 12` and
# `uwb-hil demo`: the host firmware is compiled from the sources the wheel ships into a fresh per-user cache
# (harness/firmware_cache.py; only a C compiler needed). Then a pytest session of an unrelated project in that
# environment must show no uwb-hil header (the plugin is inert unless asked for).
# Usage: check_wheel_install.sh [WORK_DIR] (default: a new temporary directory, removed afterwards).
set -euo pipefail
REPO=$(cd "$(dirname "$0")/.." && pwd)
PYTHON=${PYTHON:-python3}
WORK=${1:-}
if [ -z "$WORK" ]; then
    WORK=$(mktemp -d /tmp/uwb-hil-wheel.XXXXXX)
    trap 'rm -rf "$WORK"' EXIT
fi
rm -rf "$WORK/dist" "$WORK/venv" "$WORK/cache" "$WORK/elsewhere"
mkdir -p "$WORK/dist" "$WORK/elsewhere"
"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q --upgrade pip setuptools 2>&1 | grep -v "^WARNING: Location" || true
# setuptools warns at length about the firmware's C folders as data directories: kept in the log
if ! (cd "$REPO" && "$WORK/venv/bin/python" -m pip wheel -q --no-deps -w "$WORK/dist" . > "$WORK/wheel.log" 2>&1); then
    cat "$WORK/wheel.log" >&2
    exit 1
fi
WHEEL=$(ls "$WORK"/dist/uwb_hil-*.whl)
"$WORK/venv/bin/python" -m pip install -q "$WHEEL" 2>&1 | grep -v "^WARNING: Location" || true
cd "$WORK/elsewhere"
export UWB_HIL_CACHE="$WORK/cache"
"$WORK/venv/bin/uwb-hil" --version
"$WORK/venv/bin/uwb-hil" run --duration 12 > run.txt
"$WORK/venv/bin/uwb-hil" demo --duration 3 > demo.txt
ls "$UWB_HIL_CACHE"/firmware/*/uwb-fw > /dev/null
head -1 run.txt
printf 'def test_unrelated():\n    assert True\n' > test_unrelated.py
"$WORK/venv/bin/python" -m pytest -p no:cacheprovider test_unrelated.py > pytest.txt
if grep -q "^uwb-hil:" pytest.txt; then
    echo "check_wheel_install: the pytest plugin printed in an unrelated project:" >&2
    cat pytest.txt >&2
    exit 1
fi
echo "check_wheel_install: $(basename "$WHEEL") installed outside the checkout: run and demo pass, firmware built into the cache, pytest plugin inert"
