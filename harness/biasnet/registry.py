"""The model registry: the networks the project ships (`make models`, firmware_sim/models/models.json), found
by name or by what they are for, and whether a device's network can run on a flight. No PyTorch here: the
light install (`uwb-hil run` without the [train] extra) reads it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from harness.config import MODE_UWB_ONLY, STAGE_BIAS_NN, EstimatorConfig
from harness.errors import InputError
from harness import kinds
from harness.flight.data import KIND_TDOA, KIND_TWR, Flight
from harness.paths import MODELS_DIR, REPO_ROOT
from harness.twin.features import LAYOUT_TDOA_POS, LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE

#: models.json: each shipped model's file, hash, training and held-out figures, under its name
SUMMARY = MODELS_DIR / "models.json"


@dataclass(frozen=True)
class ShippedModel:
    """A network trained on the shared recordings (not committed: `make models` builds it)."""
    name: str          # its key in models.json
    family: str        # the recordings it was trained on (campaign/plan.py's recorded families)
    kind: int          # the measurement kind it corrects (KIND_TWR / KIND_TDOA)
    layout: int        # its input layout (harness/twin/features.py)

    @property
    def path(self) -> Path:
        return MODELS_DIR / f"{self.name}.npz"

    @property
    def repo_path(self) -> str:
        """The path as a user types it from the repository root."""
        return str(self.path.relative_to(REPO_ROOT))


RECORDED_MODELS: dict[str, ShippedModel] = {
    "util": ShippedModel("util_tdoa_pos", "util", KIND_TDOA, LAYOUT_TDOA_POS),
    "rcv_twr": ShippedModel("rcv_twr", "rcv_twr", KIND_TWR, LAYOUT_TWR_POSE),
    "cf_usd": ShippedModel("cf_tdoa_pose", "cf_usd", KIND_TDOA, LAYOUT_TDOA_POSE),
}


def kind_name(kind: int) -> str:
    return kinds.kind_of(kind).key


def takes_attitude(layout: int) -> bool:
    """Whether a network of this input layout takes roll, pitch and yaw (which a UWB-only replay lacks)."""
    return layout in (LAYOUT_TWR_POSE, LAYOUT_TDOA_POSE)


def position_only_model(kind: int) -> ShippedModel | None:
    """The shipped network without attitude inputs for this measurement kind, if there is one."""
    return next((m for m in RECORDED_MODELS.values() if m.kind == kind and not takes_attitude(m.layout)), None)


def position_only_hint(kind: int) -> str:
    """Where to get a network without attitude inputs for this measurement kind."""
    train = f"train one with `uwb-hil train --recording ... --layout pos --out {kind_name(kind)}_pos.npz`"
    model = position_only_model(kind)
    if model is not None:
        return f"--model {model.repo_path} (built by `make models`), or {train}"
    return train


def check_network_inputs(flight: Flight, cfg: EstimatorConfig, layouts: tuple[int, int]) -> None:
    """Refuse to run a bias network that takes the attitude (pose layout) where the firmware has none: a
    UWB-only replay (no IMU, or --uwb-only) feeds it a level attitude, and its correction is then made up.
    `layouts` = the device's (TWR, TDoA) network layouts from HELLO."""
    if not cfg.stages & STAGE_BIAS_NN or cfg.mode != MODE_UWB_ONLY:
        return
    kind = flight.uwb.kind
    layout = dict(zip(("twr", "tdoa"), layouts)).get(kinds.kind_of(kind).network or "", 0)
    if not takes_attitude(layout):
        return
    why = "has no IMU" if not flight.has_imu else "is replayed with --uwb-only"
    raise InputError(f"the device's {kind_name(kind).upper()} bias network takes roll, pitch and yaw (pose layout "
                     f"{layout}), but {flight.name} {why}: the firmware has no attitude to give it and its correction "
                     f"would be made up. Use a position-only network ({position_only_hint(kind)}), or --stages outlier, or "
                     "pass --force to run it anyway")
