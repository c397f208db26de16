"""Fixtures shared by the STM32/QEMU tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def arm_tools() -> None:
    """The toolchain and QEMU, installed on demand (idempotent script); skip if that is impossible."""
    from harness.stm32_build import BuildError, ensure_tools
    try:
        ensure_tools()
    except BuildError as exc:
        pytest.skip(str(exc))
