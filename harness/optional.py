"""Optional dependencies: PyTorch is the [train] extra (`pip install 'uwb-hil[train]'`).

Only bias-network training (`uwb-hil train`, `uwb-hil models`, the training bench) and the M4 network
bench's agreement check use it, and they import it through `require_torch` at call time, so the rest of
the harness (run, demo, fly, campaign, report, eval-bias, the pytest plugin) works without it.
"""

from __future__ import annotations

from types import ModuleType

from harness.errors import UwbHilError

TRAIN_EXTRA_HINT = ("pip install 'uwb-hil[train]' (from a checkout: pip install -e '.[train]'; "
                    "`make` installs it with the pinned CPU build, constraints.txt)")


class MissingDependencyError(UwbHilError):
    """An optional dependency is not installed; the message says which extra provides it."""


def require_torch(what: str) -> ModuleType:
    """The torch module, or MissingDependencyError naming `what` needs it and how to install it."""
    try:
        import torch
    except ImportError as exc:
        raise MissingDependencyError(f"{what} needs PyTorch, which is not installed ({exc}): "
                                     f"{TRAIN_EXTRA_HINT}") from None
    return torch
