# Sourced by the ensure_*.sh scripts (scripts/, firmware_sim/fuzz/): install missing Debian packages
# non-interactively, as root or with passwordless sudo. Every message goes to stderr (ensure_clang.sh
# prints its result on stdout).
#
#   apt_ready NAME WHAT...   exit 1 with the reason unless packages can be installed (UWB_NO_INSTALL=1
#                            only checks; not root and no passwordless sudo; no apt-get), else run
#                            `apt-get update` once; NAME prefixes the messages, WHAT names what is missing
#   apt_get_install PKG...   install the packages (after apt_ready)

APT_SUDO=""

apt_ready() {
    local name=$1
    shift
    if [ "${UWB_NO_INSTALL:-0}" = "1" ]; then
        echo "$name: missing $* (UWB_NO_INSTALL=1, not installing)" >&2
        exit 1
    fi
    if [ "$(id -u)" -ne 0 ]; then
        if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
            APT_SUDO="sudo -n env DEBIAN_FRONTEND=noninteractive"  # sudo drops the environment
        else
            echo "$name: missing $*; not root and no passwordless sudo." >&2
            echo "  install with: apt-get install --no-install-recommends $*" >&2
            exit 1
        fi
    fi
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "$name: missing $* and apt-get is not available" >&2
        exit 1
    fi
    echo "$name: installing $*" >&2
    export DEBIAN_FRONTEND=noninteractive
    $APT_SUDO apt-get -o DPkg::Lock::Timeout=900 update -q >/dev/null
}

apt_get_install() {
    $APT_SUDO apt-get -o DPkg::Lock::Timeout=900 install -y -q --no-install-recommends "$@" >/dev/null
}
