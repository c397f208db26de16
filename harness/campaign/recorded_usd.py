"""The Crazyflie uSD flights of a campaign's recorded section (issue 28): real flights logged on board with
IMU, TDoA and the motion-capture pose with attitude (../shared/data/cf_usd, harness/flight/formats/cf_usd*.py).

Every shared flight is replayed twice: with the IMU (the firmware's full EKF, the way the Crazyflie runs it)
and UWB-only (constant-velocity model, `--uwb-only`), in each configuration. The network is the real-flight
one (firmware_sim/models/cf_tdoa_pose.npz, `make models`: pose layout, trained on the line-of-sight flights
of 0425 other than 3, 8, 13, 18). Its configurations run only where they mean something: with the IMU (the
network takes the firmware's own roll, pitch and yaw; UWB-only has none) and on flights it was not trained
on (the evaluation flights and the two shelf flights); the training flights give the IMU vs UWB-only
comparison without it. Every log is read with the tag's lever arm calibrated on other flights
(recipes.cf_usd_lever_arms), as the network's training and docs/real-flights.md. The report's section is
harness/report/usd_section.py.
"""

from __future__ import annotations

from pathlib import Path

from harness.biasnet.recipes import CF_USD_EVAL, CF_USD_LOS, CF_USD_SHELF, cf_usd_lever_arms
from harness.biasnet.registry import RECORDED_MODELS
from harness.campaign.flight_spec import FlightSpec
from harness.errors import InputError

#: models.json key and file of the real-flight network
CF_MODEL_KEY = RECORDED_MODELS["cf_usd"].name
CF_MODEL = RECORDED_MODELS["cf_usd"].path
#: the trajectory label of a uSD flight: "cf-<log name>", with UWB_ONLY_SUFFIX when replayed UWB-only
LABEL_PREFIX = "cf-"
UWB_ONLY_SUFFIX = "-uwb"
#: ... and TOF_SUFFIX when replayed with the IMU and the flow deck's ToF ranger (logs with readings only)
TOF_SUFFIX = "-tof"


def log_name(trajectory: str) -> str:
    """The log's name in a uSD flight's trajectory label."""
    return trajectory.removeprefix(LABEL_PREFIX).removesuffix(UWB_ONLY_SUFFIX).removesuffix(TOF_SUFFIX)


def replay_of(trajectory: str) -> str:
    """How a uSD flight is replayed: "uwb" (UWB-only), "tof" (IMU + ToF ranger) or "imu"."""
    if trajectory.endswith(UWB_ONLY_SUFFIX):
        return "uwb"
    return "tof" if trajectory.endswith(TOF_SUFFIX) else "imu"


def is_usd(trajectory: str) -> bool:
    """Whether a recorded run's trajectory label is a Crazyflie uSD flight."""
    return trajectory.startswith(LABEL_PREFIX)


def usd_role(trajectory: str) -> str:
    """"held-out" (an evaluation flight), "shelf" (0426, obstacle) or "training" (the network saw it)."""
    name = log_name(trajectory)
    if any(Path(r).name == name for r in CF_USD_SHELF):
        return "shelf"
    return "held-out" if any(Path(r).name == name for r in CF_USD_EVAL) else "training"


def usd_flights(data_dir: Path, with_models: bool = True
                ) -> tuple[list[FlightSpec], list[str], dict[str, str | None]]:
    """The shared uSD flights present under data_dir (each with the IMU and UWB-only), notes, and the model
    file per flight id (the real-flight network when it is built, else None: the firmware's default)."""
    flights: list[FlightSpec] = []
    notes: list[str] = []
    models: dict[str, str | None] = {}
    rels = [*CF_USD_LOS, *CF_USD_SHELF]
    if not any((data_dir / r).is_file() for r in rels):
        return flights, notes, models            # no uSD data here at all: not a campaign about it
    model = str(CF_MODEL) if with_models and CF_MODEL.is_file() else None
    try:
        levers = cf_usd_lever_arms(data_dir)     # the tag point the network is trained and judged on
    except InputError as e:
        levers = {}
        notes.append(f"Crazyflie uSD flights read with UTIL's lever arm: no calibration ({e})")
    if with_models and model is None:
        notes.append(f"{CF_MODEL} not found (`make models` builds it): Crazyflie flights run on the firmware's "
                     "default network")
    for rel in rels:
        path = data_dir / rel
        if not path.is_file():
            notes.append(f"recorded flight {path} not found: skipped")
            continue
        for suffix, uwb_only, tof in _replays(path, notes):
            f = FlightSpec(source="recorded", mode="tdoa", trajectory=LABEL_PREFIX + path.name + suffix, path=str(path),
                           uwb_only=uwb_only, lever_arm=levers.get(path.name), tof=tof)
            flights.append(f)
            models[f.flight_id] = model
    logs = len({f.path for f in flights})
    notes.append(f"Crazyflie uSD flights: {logs} logs, each with the IMU and UWB-only, and with the IMU and the ToF "
                 f"ranger where the log has its readings ({sum(f.tof for f in flights)}); the network's "
                 f"configurations only on flights it was not trained on ({', '.join(Path(r).name for r in CF_USD_EVAL)}"
                 f", {', '.join(Path(r).name for r in CF_USD_SHELF)})")
    return flights, notes, models


def _replays(path: Path, notes: list[str]) -> list[tuple[str, bool, bool]]:
    """(label suffix, UWB-only, ToF) of each replay of one log: the paper's system (IMU, no ranger), UWB-only,
    and IMU + ToF ranger when the log has readings (`uwb-hil run`'s default on such a log)."""
    from harness.flight.formats.cf_usd_summary import usd_summary
    from harness.flight.formats.common import RecordingError
    replays = [("", False, False), (UWB_ONLY_SUFFIX, True, False)]
    try:
        if usd_summary(path).has_tof_readings:
            replays.append((TOF_SUFFIX, False, True))
    except RecordingError as e:     # the replays themselves fail with the reason; the plan says it here
        notes.append(f"{path.name}: not readable at plan time ({e}): no ToF replay planned")
    return replays


def trained_on(model: str | None, spec: FlightSpec) -> bool:
    """Whether `model`'s network for the flight's kind names this recording among its training data."""
    if model is None or spec.path is None:
        return False
    from harness.biasnet.network import BiasModel
    names = BiasModel.load(Path(model)).meta.get(f"{spec.mode}_trained_on") or []
    path = Path(spec.path).as_posix()
    return any(not str(n).startswith("sim:") and path.endswith("/" + str(n).lstrip("/")) for n in names)
