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

if [ "${UWB_NO_INSTALL:-0}" = "1" ]; then
    echo "ensure_arm_tools: missing ${missing[*]} (UWB_NO_INSTALL=1, not installing)" >&2
    exit 1
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO="sudo -n env DEBIAN_FRONTEND=noninteractive"  # sudo drops the environment
    else
        echo "ensure_arm_tools: missing ${missing[*]}; not root and no passwordless sudo." >&2
        echo "  install them with: apt-get install --no-install-recommends ${missing[*]}" >&2
        exit 1
    fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure_arm_tools: missing ${missing[*]} and apt-get is not available" >&2
    exit 1
fi

echo "ensure_arm_tools: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q >/dev/null
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null

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
