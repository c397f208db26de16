#!/usr/bin/env bash
# The light install: a fresh virtualenv with `pip install -e .` (no extras, so no PyTorch). `uwb-hil demo`
# and `uwb-hil run --recording ...` must work; `uwb-hil train` must exit 2 saying how to install the
# [train] extra. Needs the host firmware (make firmware). Usage: check_light_install.sh [VENV_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${1:-build/light-venv}
PYTHON=${PYTHON:-python3}
FIX=tests/fixtures/recordings

rm -rf "$VENV"
"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q -e . 2>&1 | grep -v "^WARNING: Location" || true
if "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    echo "check_light_install: torch is importable in $VENV: the core install must not pull it in" >&2
    exit 1
fi
"$VENV/bin/uwb-hil" demo --duration 3 --json > "$VENV/demo.json"
"$VENV/bin/uwb-hil" run --recording "$FIX/const1-fixture-tdoa2.csv" --anchors "$FIX/anchors.csv" \
    --stages outlier --json > "$VENV/run.json"
set +e
"$VENV/bin/uwb-hil" train --mode twr --flights 2 --duration 5 --out "$VENV/m.npz" 2> "$VENV/train.err"
rc=$?
set -e
if [ "$rc" -ne 2 ] || ! grep -q "uwb-hil\[train\]" "$VENV/train.err"; then
    echo "check_light_install: uwb-hil train without torch: exit $rc (want 2 with the install hint):" >&2
    cat "$VENV/train.err" >&2
    exit 1
fi
echo "check_light_install: demo and run work without torch; train says: $(cat "$VENV/train.err")"
