#!/usr/bin/env bash
# Make sure clang with libFuzzer + ASan/UBSan runtimes is present (Debian: clang, libclang-rt-*-dev).
# Idempotent: does nothing when a probe build of a libFuzzer program links; otherwise installs only
# what is missing with apt-get (root, or passwordless sudo). Prints the clang command on stdout.
# Set UWB_NO_INSTALL=1 to only check. Exit 1 (reason on stderr) when clang is still unusable.
set -euo pipefail

find_clang() {
    local c
    for c in "${CLANG:-}" clang clang-19 clang-16 clang-14; do
        [ -n "$c" ] && command -v "$c" >/dev/null 2>&1 && { echo "$c"; return 0; }
    done
    return 1
}

# A one-line fuzz target must compile and link with the fuzzer and both sanitizers.
probe() {
    local cc=$1 dir
    dir=$(mktemp -d)
    printf '#include <stddef.h>\n#include <stdint.h>\nint LLVMFuzzerTestOneInput(const uint8_t *d, size_t n){(void)d;(void)n;return 0;}\n' \
        >"$dir/p.c"
    if "$cc" -fsanitize=fuzzer,address,undefined -o "$dir/p" "$dir/p.c" >/dev/null 2>&1; then
        rm -rf "$dir"; return 0
    fi
    rm -rf "$dir"; return 1
}

if cc=$(find_clang) && probe "$cc"; then
    echo "$cc"; exit 0
fi
# shellcheck source=../../scripts/apt_install.sh
. "$(dirname "$0")/../../scripts/apt_install.sh"
apt_ready ensure_clang clang libclang-rt-dev
pkgs=(clang)
# The runtimes (libclang_rt.fuzzer, asan, ubsan) live in libclang-rt-N-dev on Debian >= 12.
ver=$(apt-cache depends clang 2>/dev/null | sed -n 's/.*Depends: clang-\([0-9][0-9]*\)$/\1/p' | head -1)
if [ -n "$ver" ] && apt-cache show "libclang-rt-$ver-dev" >/dev/null 2>&1; then
    pkgs+=("libclang-rt-$ver-dev")
fi
apt_get_install "${pkgs[@]}"
if cc=$(find_clang) && probe "$cc"; then
    echo "$cc"; exit 0
fi
echo "ensure_clang: clang installed but a libFuzzer+ASan+UBSan probe build still fails" >&2
exit 1
