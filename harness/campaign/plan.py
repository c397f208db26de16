"""What a campaign runs: one RunSpec per (flight, configuration), grouped by flight.

Simulated flights: {twr, tdoa} x trajectories x seeds, each flown in the three configurations of the paper
(none, outlier, outlier+nn) and in outlier+nn+std (the network's own std as the measurement std, stage NN_STD:
the configuration whose filter is consistent with the network, docs/bias-network.md). Seeds start at 1000 so they are disjoint from the seeds the bias network was
trained on (training uses seeds < 1000; recorded in every run's summary as ``seed_disjoint_from_training``).

Recorded flights: the held-out UTIL TDoA trials (trial 5 of const1/const2 and all of const3: the real-data
network is trained on const1/const2 trials 1-4) and the held-out rcv_twr sequence(s), replayed in UWB-only
mode, through a firmware carrying the network trained on that data (firmware_sim/models/util_tdoa_pos.npz,
rcv_twr.npz; the held-out lists are checked against firmware_sim/models/models.json). The Crazyflie uSD
flights (IMU + TDoA + attitude) are replayed with the IMU and UWB-only: harness/campaign/recorded_usd.py.
A recorded flight its network was trained on runs no network configuration.
Simulated flights run on the firmware's compiled-in default model (trained on simulated flights).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from harness.config import PAPER_PRESETS, PRESETS, STAGE_BIAS_NN, config_with
from harness.biasnet.registry import RECORDED_MODELS as SHIPPED_RECORDED
from harness.biasnet.registry import SUMMARY as MODELS_SUMMARY
from harness.campaign.flight_spec import FlightSpec
from harness.errors import InputError
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir
from harness.stream.streamer import PACING_MODES

MODES = ("twr", "tdoa")
TRAJECTORIES = ("circle", "circle-z")
#: The paper's three, and the network with its std (NEES inside the bounds); any key of PRESETS may be asked for
CONFIGS = (*PAPER_PRESETS, "outlier+nn+std")
FIRST_EVAL_SEED = 1000              # training seeds are below this
MAX_DURATION_S = 3600.0             # of one simulated flight (memory: the flight is built whole)
RADIO_PROTOCOLS = ("tdoa2", "tdoa3")
# Held out from training (see the module docstring). Paths relative to the shared data directory.
UTIL_HELD_OUT = (
    "util/const1/const1-trial5-tdoa2-extracted.csv",
    "util/const1/const1-trial5-tdoa3-extracted.csv",
    "util/const2/const2-trial5-tdoa2-extracted.csv",
    "util/const3/const3-trial1-tdoa2-extracted.csv",
    "util/const3/const3-trial2-tdoa2-extracted.csv",
)
UTIL_ANCHORS = "util/anchors.csv"
RCV_TWR_HELD_OUT = ("rcv_twr/sequence5",)     # the rcv_twr network is trained on sequences 1-4
#: Real-data networks per recorded family (key in models.json, file): the model registry's
RECORDED_MODELS = {family: (model.name, model.path) for family, model in SHIPPED_RECORDED.items()}


class PlanError(InputError):
    """A campaign option is invalid (names the option)."""


ROLE_ACCURACY = "accuracy"
ROLE_LATENCY = "latency"
# Radio-level flight sets (kept out of the accuracy and latency figures): the flight streamed as anchor
# packets through the tag's TDoA engine, and the same flight's differences (its measurement-level twin).
ROLE_RADIO = "radio"
ROLE_RADIO_MEAS = "radio-meas"


@dataclass(frozen=True)
class RunSpec:
    """One flight in one configuration. Accuracy runs stream as fast as the device answers (windowed: the
    same estimates as lockstep); latency runs replay at the data's own clock (realtime), so their end-to-end
    latency is what a sensor-paced board would see, without queueing behind a window."""

    flight: FlightSpec
    config: str                    # a key of harness.config.PRESETS
    firmware: str = str(DEFAULT_FIRMWARE)
    pacing: str = "windowed"
    role: str = ROLE_ACCURACY
    model: str | None = None       # bias model (.npz) the firmware must carry; None: its compiled-in default
    model_hash: str | None = None  # expected HELLO model hash (checked before the run), once known
    settings: tuple[str, ...] = ()  # estimator overrides FIELD=VALUE (harness.config.config_with)

    @property
    def run_id(self) -> str:
        suffix = {ROLE_LATENCY: "-latency", ROLE_RADIO_MEAS: "-meas"}.get(self.role, "")
        return f"{self.flight.flight_id}-{self.config.replace('+', '-')}{suffix}"

    def as_dict(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "flight_id": self.flight.flight_id, "config": self.config,
                "firmware": self.firmware, "pacing": self.pacing, "role": self.role, "model": self.model,
                "model_hash": self.model_hash, "flight": self.flight.as_dict()} | (
                    {"settings": list(self.settings)} if self.settings else {})  # absent: old fingerprints hold

    def fingerprint(self) -> str:
        """Changes whenever anything that decides the run's outcome changes (resume compares it)."""
        text = json.dumps(self.as_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @staticmethod
    def from_dict(d: dict[str, Any]) -> RunSpec:
        return RunSpec(flight=FlightSpec(**d["flight"]), config=str(d["config"]), firmware=str(d["firmware"]),
                       pacing=str(d.get("pacing", "windowed")), role=str(d.get("role", ROLE_ACCURACY)),
                       model=d.get("model"), model_hash=d.get("model_hash"),
                       settings=tuple(str(x) for x in d.get("settings", ())))


@dataclass(frozen=True)
class CampaignOptions:
    seeds: int = 10
    first_seed: int = FIRST_EVAL_SEED
    duration_s: float = 70.0
    modes: tuple[str, ...] = MODES
    trajectories: tuple[str, ...] = TRAJECTORIES
    configs: tuple[str, ...] = CONFIGS
    recorded: bool = True
    data_dir: Path = field(default_factory=shared_data_dir)
    firmware: Path = DEFAULT_FIRMWARE
    takeoff: bool = True           # simulated flights start and end on the ground (needs duration > 10.5 s)
    pacing: str = "windowed"       # of the accuracy runs
    latency_runs: bool = True      # per mode, one extra real-time run (outlier+nn) of the first flight
    sim_model: Path | None = None  # None: the firmware's compiled-in default model
    recorded_models: bool = True   # recorded flights on a firmware with the real-data network (if present)
    settings: tuple[str, ...] = ()  # estimator overrides FIELD=VALUE for every run (`--set`)
    radio: tuple[str, ...] = ()    # LPS radio-level flight sets: the TDoA flights (simulated, and held-out
    #                                UTIL recordings of that protocol) again at radio level, both levels flown

    def validate(self) -> None:
        """Everything that would make every worker fail is refused here, before any worker starts."""
        from harness.flight.scenarios import SCENARIOS, min_duration_s
        if self.seeds < 0:
            raise PlanError(f"--seeds must be >= 0, got {self.seeds}")
        if self.first_seed < 0:
            raise PlanError(f"--first-seed must be >= 0, got {self.first_seed}")
        shortest = min_duration_s(self.takeoff)
        if self.seeds and not (shortest < self.duration_s <= MAX_DURATION_S):
            raise PlanError(f"--duration {self.duration_s:g}: simulated flights need more than {shortest:g} s "
                            f"({'take-off, landing and ' if self.takeoff else ''}the scenario itself) "
                            f"and at most {MAX_DURATION_S:g} s")
        for traj in self.trajectories:
            if traj not in SCENARIOS:
                raise PlanError(f"unknown trajectory {traj!r} in --trajectories; choose from {SCENARIOS}")
        if not Path(self.firmware).is_file():
            raise PlanError(f"firmware binary {self.firmware} not found: run `make firmware` (or pass --firmware)")
        if self.sim_model is not None and not Path(self.sim_model).is_file():
            raise PlanError(f"--sim-model {self.sim_model}: file not found")
        try:
            config_with(self.settings)
        except ValueError as exc:
            raise PlanError(str(exc)) from None
        for mode in self.modes:
            if mode not in MODES:
                raise PlanError(f"unknown mode {mode!r} in --modes; choose from {MODES}")
        for cfg in self.configs:
            if cfg not in PRESETS:
                raise PlanError(f"unknown configuration {cfg!r}; choose from {tuple(PRESETS)}")
        if self.pacing not in PACING_MODES:
            raise PlanError(f"unknown pacing {self.pacing!r}; choose from {PACING_MODES}")
        if not self.trajectories and self.seeds:
            raise PlanError("--trajectories is empty")
        for protocol in self.radio:
            if protocol not in RADIO_PROTOCOLS:
                raise PlanError(f"unknown radio protocol {protocol!r} in --radio; choose from {RADIO_PROTOCOLS}")
        if self.radio and "tdoa" not in self.modes:
            raise PlanError("--radio flies TDoA flights at radio level: it needs tdoa in --modes")


def held_out(family: str) -> tuple[tuple[str, ...], str]:
    """Held-out recordings of a family (paths relative to the data dir) and a note on the training's own list.

    The list is fixed here (the training split: UTIL const1/const2 trials 1-4 and rcv_twr sequences 1-4 are
    training data, everything else is held out); models.json's "heldout" (the flights the training chose to
    evaluate on) is only compared, since it may list fewer flights than are unseen."""
    key, _ = RECORDED_MODELS[family]
    rels = UTIL_HELD_OUT if family == "util" else RCV_TWR_HELD_OUT
    info = MODELS_SUMMARY
    try:
        names = set((json.loads(info.read_text(encoding="utf-8")).get(key) or {}).get("heldout") or {})
    except (OSError, ValueError):
        return rels, f"{info} not readable: held-out list not cross-checked"
    ours = {Path(r).name if family == "util" else r for r in rels}
    if names and not names <= ours:
        return rels, f"{info} ({key}.heldout) names flights outside this list: {sorted(names - ours)}"
    return rels, f"{key}.heldout of {info.name} is a subset of this list"


def recorded_flights(data_dir: Path, modes: tuple[str, ...], with_models: bool = True
                     ) -> tuple[list[FlightSpec], list[str], dict[str, str | None]]:
    """The held-out recordings present under data_dir, notes (missing files, split source), and the model
    file per flight id (None: the firmware's default)."""
    flights: list[FlightSpec] = []
    notes: list[str] = []
    models: dict[str, str | None] = {}
    for family, mode in (("util", "tdoa"), ("rcv_twr", "twr")):
        if mode not in modes:
            continue
        rels, check = held_out(family)
        notes.append(f"held-out {family} recordings: {', '.join(rels)} ({check})")
        model_file = RECORDED_MODELS[family][1]
        model = str(model_file) if with_models and model_file.is_file() else None
        if with_models and model is None:
            notes.append(f"{model_file} not found: {family} flights run on the firmware's default model")
        for rel in rels:
            path = data_dir / rel
            if family == "util":
                anchors = data_dir / UTIL_ANCHORS
                if not path.is_file() or not anchors.is_file():
                    notes.append(f"recorded flight {path} (or {anchors}) not found: skipped")
                    continue
                label = "util-" + path.name.replace("-extracted.csv", "")
                f = FlightSpec(source="recorded", mode=mode, trajectory=label, path=str(path),
                               anchors=str(anchors), uwb_only=True)
            else:
                if not path.is_dir():
                    notes.append(f"recorded sequence {path} not found: skipped")
                    continue
                f = FlightSpec(source="recorded", mode=mode, trajectory="rcv-" + path.name, path=str(path),
                               uwb_only=True)
            flights.append(f)
            models[f.flight_id] = model
    if "tdoa" in modes:
        from harness.campaign.recorded_usd import usd_flights
        usd, usd_notes, usd_models = usd_flights(data_dir, with_models)
        flights, notes = flights + usd, notes + usd_notes
        models.update(usd_models)
    return flights, notes, models


def _refuse_missing_recordings(data_dir: Path, notes: list[str]) -> None:
    """Recorded flights asked for (--recorded, the default) but absent are an input error, not a silent skip."""
    missing = [n for n in notes if n.endswith("not found: skipped")]
    if not missing:
        return
    where = (f"the data folder {data_dir} does not exist" if not data_dir.is_dir()
             else f"{len(missing)} held-out recording(s) missing under {data_dir}, e.g. {missing[0]}")
    raise PlanError(f"recorded flights asked for but {where}: give --data-dir DIR (or $UWB_HIL_DATA), or "
                    "--no-recorded (or UWB_HIL_NO_RECORDED=1)")


def plan_campaign(opts: CampaignOptions) -> tuple[list[RunSpec], list[str]]:
    """Every run of the campaign (simulated first), plus notes on what was left out and why."""
    opts.validate()
    flights: list[FlightSpec] = []
    for mode in opts.modes:
        for traj in opts.trajectories:
            for k in range(opts.seeds):
                flights.append(FlightSpec(source="sim", mode=mode, trajectory=traj, seed=opts.first_seed + k,
                                          duration_s=float(opts.duration_s), takeoff=opts.takeoff))
    notes: list[str] = []
    models: dict[str, str | None] = {f.flight_id: (str(opts.sim_model) if opts.sim_model else None) for f in flights}
    if opts.recorded:
        rec, notes, rec_models = recorded_flights(Path(opts.data_dir), opts.modes, opts.recorded_models)
        _refuse_missing_recordings(Path(opts.data_dir), notes)
        flights += rec
        models.update(rec_models)
    if not flights:
        raise PlanError("no runs planned (--seeds 0 and no recorded flight): a campaign that flies nothing "
                        "cannot pass; give --seeds N or recorded data")
    blind = {f.flight_id for f in flights if f.uwb_only and _needs_attitude(models[f.flight_id], f.mode)}
    notes += _left_out_notes(flights, blind, models, "replayed UWB-only, and the network ({model}) takes roll, pitch "
                             "and yaw: its configurations are left out (a level attitude would make the correction "
                             "up; `uwb-hil run` refuses the same)")
    from harness.campaign.recorded_usd import trained_on
    seen = {f.flight_id for f in flights if f.source == "recorded" and trained_on(models[f.flight_id], f)} - blind
    notes += _left_out_notes(flights, seen, models, "the network ({model}) was trained on it: its configurations "
                             "are left out")
    blind |= seen
    runs = [RunSpec(flight=f, config=c, firmware=str(opts.firmware), pacing=opts.pacing, model=models[f.flight_id])
            for f in flights for c in opts.configs
            if not (f.flight_id in blind and PRESETS[c] & STAGE_BIAS_NN)]
    if opts.latency_runs:
        for mode in opts.modes:
            first = next((f for f in flights if f.source == "sim" and f.mode == mode), None)
            if first is not None:
                cfg = "outlier+nn" if "outlier+nn" in opts.configs else opts.configs[-1]
                runs.append(RunSpec(flight=first, config=cfg, firmware=str(opts.firmware), pacing="realtime",
                                    role=ROLE_LATENCY, model=models[first.flight_id]))
    runs += radio_runs(opts, flights, models)
    return ([replace(r, settings=opts.settings) for r in runs] if opts.settings else runs), notes


def _left_out_notes(flights: list[FlightSpec], ids: set[str], models: dict[str, str | None], why: str) -> list[str]:
    """One note per network for the flights `ids` whose network configurations are left out: the flights, then
    `why` (with {model}); one note for all of them, not one per flight (36 on the shared uSD logs)."""
    by_model: dict[str | None, list[str]] = {}
    for f in flights:
        if f.flight_id in ids:
            by_model.setdefault(models[f.flight_id], []).append(f.trajectory)
    return [f"{', '.join(trajs)}: {why.format(model=model)}" for model, trajs in by_model.items()]


def _needs_attitude(model: str | None, mode: str) -> bool:
    """Whether the network of `model` for this measurement kind takes the attitude (pose layout)."""
    if model is None:
        return False
    from harness.biasnet.network import BiasModel
    from harness.biasnet.registry import takes_attitude
    net = getattr(BiasModel.load(Path(model)), mode)
    return net is not None and takes_attitude(net.layout)


def radio_runs(opts: CampaignOptions, flights: list[FlightSpec], models: dict[str, str | None]) -> list[RunSpec]:
    """Per protocol of opts.radio: every simulated TDoA flight, and every recorded UTIL flight of that protocol,
    at radio level, each configuration flown both as packets (ROLE_RADIO) and as the same flight's differences
    (ROLE_RADIO_MEAS): the two levels of one flight side by side, without touching the measurement-level sets."""
    runs = []
    for protocol in opts.radio:
        for f in flights:
            if f.mode != "tdoa" or (f.source == "recorded" and (not f.trajectory.startswith("util-")
                                                                or _util_protocol(f) != protocol)):
                continue
            rf = replace(f, radio=protocol)
            for role in (ROLE_RADIO_MEAS, ROLE_RADIO):
                runs += [RunSpec(flight=rf, config=c, firmware=str(opts.firmware), pacing=opts.pacing, role=role,
                                 model=models[f.flight_id]) for c in opts.configs]
    return runs


def _util_protocol(f: FlightSpec) -> str:
    """The LPS protocol a UTIL recording was made with (its file name says: ...-tdoa2- / ...-tdoa3-)."""
    return "tdoa3" if "tdoa3" in Path(f.path or f.trajectory).name else "tdoa2"


def parse_shard(text: str) -> tuple[int, int]:
    """"K/N" (1 <= K <= N) -> (K, N)."""
    k, sep, n = str(text).partition("/")
    try:
        ki, ni = int(k), int(n)
    except ValueError:
        ki = ni = 0
    if not sep or not 1 <= ki <= ni:
        raise PlanError(f"--shard {text!r}: expected K/N with 1 <= K <= N, e.g. --shard 2/4")
    return ki, ni


def plan_digest(runs: list[RunSpec]) -> str:
    """What the runs are, without where this machine keeps things (firmware and recording paths differ between
    the machines of a sharded campaign): equal digests = the same campaign, however it was split."""
    items = []
    for r in runs:
        d = r.as_dict()
        d.pop("firmware")
        d.pop("model")                       # a path; the network itself is model_hash
        d["flight"] = {k: v for k, v in d["flight"].items() if k not in ("path", "anchors")}
        items.append(d)
    text = json.dumps(sorted(items, key=lambda d: d["run_id"]), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def group_by_flight(runs: list[RunSpec]) -> list[list[RunSpec]]:
    """Runs that share a flight and a firmware run one after another on one device (the flight is built once)."""
    groups: dict[tuple[FlightSpec, str], list[RunSpec]] = {}
    for r in runs:
        groups.setdefault((r.flight, r.firmware), []).append(r)
    return list(groups.values())


def attach_firmware(runs: list[RunSpec], build_root: Path | None = None) -> list[RunSpec]:
    """Point every run that names a model at a firmware carrying it (built once per model, cached by hash:
    harness.firmware_build.firmware_for) and record the hash the device must report."""
    from harness.firmware_build import firmware_for
    from harness.biasnet.network import BiasModel

    built: dict[str, tuple[str, str]] = {}
    out = []
    for r in runs:
        if r.model is None:
            out.append(r)
            continue
        if r.model not in built:
            model = BiasModel.load(Path(r.model))
            built[r.model] = (str(firmware_for(model, build_root)), model.hash_hex)
        fw, h = built[r.model]
        out.append(replace(r, firmware=fw, model_hash=h))
    return out
