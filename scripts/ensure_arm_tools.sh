#!/usr/bin/env bash
# Make sure the STM32/QEMU toolchain is present: arm-none-eabi-gcc (+ newlib for libm),
# arm-none-eabi-size and qemu-system-arm. Idempotent and non-interactive: does nothing when all
# tools are found; otherwise runs `apt-get update` once and installs only the missing packages.
# Exit status: 0 when every tool is available afterwards, 1 otherwise (with the reason on stderr).
# Set UWB_NO_INSTALL=1 to only check (never install).
set -euo pipefail

# package -> a file that proves it is installed
declare -A PROBE=(
    [gcc-arm-none-eabi]="arm-none-eabi-gcc"
    [binutils-arm-none-eabi]="arm-none-eabi-size"
    [qemu-system-arm]="qemu-system-arm"
)

missing=()
for pkg in gcc-arm-none-eabi binutils-arm-none-eabi qemu-system-arm; do
    command -v "${PROBE[$pkg]}" >/dev/null 2>&1 || missing+=("$pkg")
done
# newlib provides libm.a / libc.a for the hard-float multilib; probe via the compiler.
newlib_ok() {
    command -v arm-none-eabi-gcc >/dev/null 2>&1 || return 1
    local lib
    lib=$(arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16 \
        -print-file-name=libm.a 2>/dev/null) || return 1
    [ -f "$lib" ]
}
newlib_ok || missing+=(libnewlib-arm-none-eabi)

if [ ${#missing[@]} -eq 0 ]; then
    echo "ensure_arm_tools: arm-none-eabi-gcc, newlib and qemu-system-arm present"
    exit 0
fi

# shellcheck source=apt_install.sh
. "$(dirname "$0")/apt_install.sh"
apt_ready ensure_arm_tools "${missing[@]}"
apt_get_install "${missing[@]}"

for pkg in gcc-arm-none-eabi binutils-arm-none-eabi qemu-system-arm; do
    if ! command -v "${PROBE[$pkg]}" >/dev/null 2>&1; then
        echo "ensure_arm_tools: ${PROBE[$pkg]} still missing after installing $pkg" >&2
        exit 1
    fi
done
if ! newlib_ok; then
    echo "ensure_arm_tools: newlib libm.a for cortex-m4 hard-float still missing" >&2
    exit 1
fi
echo "ensure_arm_tools: done"
