"""The host firmware of an installed uwb-hil: built on first use from the C sources the package ships, into a
per-user cache keyed by the sources' hash.

A checkout has `make firmware` (firmware_sim/build/uwb-fw, used when it exists). A package installed with
`pip install uwb-hil` (or a wheel) carries the sources as package data (uwb_hil_firmware/: core, proto, app,
host, models, and the Makefile, whose CFLAGS it uses); the first run that needs the host build compiles them
with the C compiler of the machine ($CC, else cc, gcc or clang; nothing else: no make, no git) into

    $UWB_HIL_CACHE | $XDG_CACHE_HOME/uwb-hil | ~/.cache/uwb-hil  /firmware/<sha256 of the sources, 16 hex>/uwb-fw

Later runs reuse it; other sources (another version) get another directory. The build id the firmware
reports is `src-<hash>` (a checkout's build reports its git commit).
"""

from __future__ import annotations

import hashlib
import os
import re
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path

from harness.errors import UwbHilError
from harness.paths import FIRMWARE_DIR

#: the folders of the host build's sources (firmware_sim/Makefile's CORE_SRC, HOST_SRC and headers)
SOURCE_DIRS = ("core", "proto", "app", "host", "models")
COMPILERS = ("cc", "gcc", "clang")
BUILD_TIMEOUT_S = 600.0


class FirmwareBuildError(UwbHilError):
    """The host firmware could not be built from the packaged sources (no compiler, or it failed)."""


def cache_root() -> Path:
    """$UWB_HIL_CACHE, else $XDG_CACHE_HOME/uwb-hil, else ~/.cache/uwb-hil."""
    if os.environ.get("UWB_HIL_CACHE"):
        return Path(os.environ["UWB_HIL_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "uwb-hil"


def source_files(src: Path = FIRMWARE_DIR) -> list[Path]:
    """Every .c and .h of the host build, sorted (relative order fixes the hash)."""
    files = [p for d in SOURCE_DIRS for p in sorted((src / d).glob("*.[ch]"))]
    if not any(p.suffix == ".c" for p in files):
        raise FirmwareBuildError(f"no firmware sources under {src} (expected {', '.join(SOURCE_DIRS)}/): "
                                 "reinstall uwb-hil, or build a checkout's firmware with `make firmware`")
    return files


def source_hash(src: Path = FIRMWARE_DIR) -> str:
    """sha256 over the sources' relative paths and contents, 16 hex digits."""
    h = hashlib.sha256()
    for p in source_files(src):
        h.update(p.relative_to(src).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def makefile_cflags(src: Path = FIRMWARE_DIR) -> list[str]:
    """CFLAGS of the host build as firmware_sim/Makefile (shipped with the sources) defines them: its simple
    assignments read and $(VAR) expanded (the flags live in the Makefile only; make itself is not needed)."""
    try:
        text = (src / "Makefile").read_text(encoding="utf-8")
    except OSError as exc:
        raise FirmwareBuildError(f"cannot read {src / 'Makefile'} ({exc.strerror}): reinstall uwb-hil") from None
    values: dict[str, str] = {}
    for line in text.splitlines():
        m = re.match(r"^([A-Z_]+)\s*(:=|\?=|\+=|=)\s*(.*)$", line)
        if m:
            name, op, value = m.group(1), m.group(2), m.group(3).split("#")[0].strip()
            values[name] = f"{values.get(name, '')} {value}".strip() if op == "+=" else value

    def expand(value: str, depth: int = 0) -> str:
        if depth > 10:
            return value
        return re.sub(r"\$\((\w+)\)", lambda v: expand(values.get(v.group(1), ""), depth + 1), value)

    cflags = values.get("CFLAGS")        # the default model's build: no model header (firmware_build.py's)
    if cflags is None:
        raise FirmwareBuildError(f"{src / 'Makefile'} defines no CFLAGS: reinstall uwb-hil")
    return shlex.split(expand(cflags))


def compiler() -> str:
    """$CC, else the first of cc, gcc, clang on PATH; FirmwareBuildError saying so when there is none."""
    cc = os.environ.get("CC") or next((c for c in COMPILERS if shutil.which(c)), None)
    if cc is None or shutil.which(cc.split()[0]) is None:
        raise FirmwareBuildError("the host firmware is built from its C sources on first use and needs a C "
                                 f"compiler: none found ({'$CC=' + cc if cc else ', '.join(COMPILERS)}); install "
                                 "one (Debian/Ubuntu: apt-get install gcc) or pass --firmware PATH")
    return cc


def cached_host_firmware(src: Path = FIRMWARE_DIR) -> Path:
    """The host firmware built from `src`, from the cache or compiled into it now."""
    digest = source_hash(src)
    out = cache_root() / "firmware" / digest / "uwb-fw"
    if out.is_file() and os.access(out, os.X_OK):
        return out
    cc = compiler()
    out.parent.mkdir(parents=True, exist_ok=True)
    sources = [str(p.relative_to(src)) for p in source_files(src) if p.suffix == ".c" and p.parent.name != "models"]
    fd, tmp = tempfile.mkstemp(prefix=".uwb-fw.", dir=out.parent)
    os.close(fd)
    cmd = [*cc.split(), *makefile_cflags(src), f'-DUWB_BUILD_ID="src-{digest[:7]}"', "-o", tmp, *sources, "-lm"]
    try:
        proc = subprocess.run(cmd, cwd=src, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        os.unlink(tmp)
        raise FirmwareBuildError(f"building the host firmware with {cc} failed: {exc}") from None
    if proc.returncode != 0:
        os.unlink(tmp)
        raise FirmwareBuildError(f"building the host firmware with {cc} failed (exit {proc.returncode}): "
                                 f"{(proc.stderr or proc.stdout)[-500:].strip()}")
    os.chmod(tmp, 0o755)
    os.replace(tmp, out)           # atomic: a concurrent first run sees the old state or the whole binary
    return out


def firmware_source_version(src: Path = FIRMWARE_DIR) -> str:
    """major.minor.patch of the firmware sources (app/firmware.h's FW_VERSION_*), '?' if unreadable."""
    import re
    try:
        text = (src / "app" / "firmware.h").read_text(encoding="utf-8")
    except OSError:
        return "?"
    parts = [re.search(rf"#define FW_VERSION_{k}\s+(\d+)", text) for k in ("MAJOR", "MINOR", "PATCH")]
    return ".".join(m.group(1) for m in parts if m) if all(parts) else "?"
