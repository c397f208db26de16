"""One campaign worker process: builds one flight and streams it, once per configuration, through its own
host build (on its own pty). Started by the runner as ``python -m harness.campaign.worker GROUP.json``.

Every run ends with a summary file, "ok" or "failed" (with the reason); a failing run does not stop the
next one (a dead device is restarted). The results JSONL is written by the streamer as results arrive.
"""

from __future__ import annotations

import json
import platform
import signal
import sys
import time
import traceback
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from harness.campaign.plan import FIRST_EVAL_SEED, ROLE_RADIO, FlightSpec, RunSpec
from harness.campaign.store import (STATUS_FAILED, STATUS_OK, CampaignDir, save_array_atomic, save_flight,
                                    write_json_atomic)
from harness.errors import InputError
from harness.options import CAMPAIGN_TIMEOUT_S, DEFAULT_BAUD
from harness.flight.data import Flight
from harness.report.summarize import summarize_run
from harness.device.registry import DeviceSpec, open_device
from harness.flight.run_config import run_estimator_config
from harness.stream.streamer import Pacing, Streamer
from protocol import messages as m


@dataclass(frozen=True)
class WorkerJob:
    """What the runner hands a worker (as JSON)."""

    root: str
    runs: tuple[RunSpec, ...]
    window: int = Pacing.window
    timeout_s: float = CAMPAIGN_TIMEOUT_S
    firmware_sha256: str = ""       # of the binary the runner saw (resume compares it)
    keep_jsonl: bool = False        # keep the run's JSON Lines (gzip-compressed) besides the binary rows
    # a board to run on ({"target": "serial", "port": ..., "baud": ...}: campaign/boards.py); None: the run's
    # own host build
    device: dict[str, Any] | None = None

    def to_json(self) -> str:
        return json.dumps({"root": self.root, "runs": [r.as_dict() for r in self.runs],
                           "window": self.window, "timeout_s": self.timeout_s,
                           "firmware_sha256": self.firmware_sha256, "keep_jsonl": self.keep_jsonl,
                           "device": self.device}, indent=1)

    def device_spec(self, run: RunSpec, log_dir: Path) -> DeviceSpec:
        if self.device is not None:
            return DeviceSpec(target=str(self.device["target"]), port=self.device.get("port"),
                              baud=int(self.device.get("baud", DEFAULT_BAUD)), timeout_s=self.timeout_s,
                              log_dir=log_dir)
        return DeviceSpec(firmware=Path(run.firmware), timeout_s=self.timeout_s, log_dir=log_dir)

    @staticmethod
    def from_json(text: str) -> WorkerJob:
        d = json.loads(text)
        return WorkerJob(root=d["root"], runs=tuple(RunSpec.from_dict(r) for r in d["runs"]),
                         window=int(d["window"]), timeout_s=float(d["timeout_s"]),
                         firmware_sha256=str(d.get("firmware_sha256", "")),
                         keep_jsonl=bool(d.get("keep_jsonl", False)), device=d.get("device"))


def build_flight(spec: FlightSpec) -> Flight:
    flight = _base_flight(spec)
    if spec.radio:
        from harness.flight.radio import radio_level
        # simulated: the radio simulator (its own uwb stream = the same measurements as differences);
        # recorded: packets synthesised from the recorded differences
        return radio_level(flight, spec.radio, seed=int(spec.seed if spec.seed is not None else 1))
    return flight


def _base_flight(spec: FlightSpec) -> Flight:
    if spec.source == "sim":
        from harness.flight.scenarios import scenario_flight
        return scenario_flight(spec.trajectory, mode=spec.mode, duration_s=float(spec.duration_s or 70.0),
                               seed=int(spec.seed if spec.seed is not None else FIRST_EVAL_SEED),
                               takeoff=spec.takeoff, profile=spec.profile)
    if spec.source == "recorded":
        from harness.flight.loaders import load_recording
        if spec.path is None:
            raise InputError(f"{spec.flight_id}: a recorded flight needs a path")
        from harness.flight.formats.cf_usd_flight import UsdOptions
        return load_recording(Path(spec.path), anchors=Path(spec.anchors) if spec.anchors else None,
                              usd=UsdOptions.make(lever_arm=spec.lever_arm, tof=spec.tof))
    raise InputError(f"unknown flight source {spec.source!r}")


def flight_meta(spec: FlightSpec, flight: Flight) -> dict[str, Any]:
    """What the report says about the flight, including why the network has not seen it."""
    meta: dict[str, Any] = {"flight_id": spec.flight_id, "name": flight.name, "source": spec.source,
                            "mode": spec.mode, "trajectory": spec.trajectory, "seed": spec.seed,
                            "measurements": len(flight.uwb), "duration_s": flight.duration_s,
                            "has_imu": flight.has_imu, "uwb_only": spec.uwb_only or not flight.has_imu}
    if spec.source == "sim":
        meta["seed_disjoint_from_training"] = spec.seed is not None and spec.seed >= FIRST_EVAL_SEED
    else:
        meta["held_out_from_training"] = True
        meta["path"] = spec.path
    meta["flight_meta"] = {k: v for k, v in flight.meta.items() if isinstance(v, (str, int, float, bool))}
    if flight.radio is not None:
        meta["radio"] = {"protocol": flight.radio.protocol, "packets": len(flight.radio)}
    return meta


def _failure(run: RunSpec, exc: BaseException, started: float) -> dict[str, Any]:
    return {"status": STATUS_FAILED, "fingerprint": run.fingerprint(), "spec": run.as_dict(),
            "error_type": type(exc).__name__, "error": str(exc) or repr(exc),
            "traceback": "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))[-4000:],
            "wall_s": time.time() - started, "host": platform.node()}


def run_group(job: WorkerJob) -> int:
    """Run every RunSpec of the job (they share one flight). Returns the number of failed runs."""
    cdir = CampaignDir(Path(job.root))
    cdir.make()
    first = job.runs[0]
    t0 = time.time()
    try:
        flight = build_flight(first.flight)
        flight.validate()
        meta = flight_meta(first.flight, flight)
        save_flight(cdir.flight_path(first.flight.flight_id), flight, meta)
    except Exception as exc:  # noqa: BLE001 - every run of this flight is reported as failed, with the reason
        for run in job.runs:
            write_json_atomic(cdir.summary_path(run.run_id), _failure(run, exc, t0))
        return len(job.runs)
    failed = 0
    with _Devices(job, cdir) as devices:
        for run in job.runs:
            started = time.time()
            try:
                _run_one(job, cdir, run, flight, meta, devices.get(run), started)
            except Exception as exc:  # noqa: BLE001 - reported in the run's summary; the next run goes on
                failed += 1
                write_json_atomic(cdir.summary_path(run.run_id), _failure(run, exc, started))
                devices.drop()       # the device may be dead or confused: the next run gets a fresh one
    return failed


def _run_one(job: WorkerJob, cdir: CampaignDir, run: RunSpec, flight: Flight, meta: dict[str, Any], device: Any,
             started: float) -> None:
    """Stream one run, keep its rows, write its "ok" summary."""
    pacing = Pacing(mode=run.pacing, window=job.window)
    cfg = run_estimator_config(flight, run.config, run.settings, uwb_only=run.flight.uwb_only)
    streamer = Streamer(device, timeout_s=job.timeout_s)
    radio = run.role == ROLE_RADIO
    result = streamer.run(flight, cfg, pacing, results_path=cdir.results_path(run.run_id), radio=radio)
    summary = summarize_run(result, flight, device.identity, radio_streamer=streamer if radio else None)
    save_array_atomic(cdir.array_path(run.run_id), result.results)
    cdir.finish_results(run.run_id, keep_jsonl=job.keep_jsonl)
    write_json_atomic(cdir.summary_path(run.run_id), {
        "status": STATUS_OK, "fingerprint": run.fingerprint(), "spec": run.as_dict(),
        "firmware_sha256": job.firmware_sha256,
        "flight": meta, "device": summary.pop("device"), "pacing": asdict(pacing),
        "estimator_config": asdict(cfg), "summary": summary,
        "divergences": sum(1 for e in result.errors if e.code == m.ErrorCode.DIVERGED),
        "device_errors": len(result.errors), "wall_s": time.time() - started,
        "host": platform.node()})


class _Devices:
    """A worker's device: opened for the first run that needs it, dropped after a failed run (stopping a
    broken device must not hide the run's own error), stopped at the end."""

    def __init__(self, job: WorkerJob, cdir: CampaignDir) -> None:
        self.job, self.cdir = job, cdir
        self._stack = ExitStack()
        self._device: Any = None

    def get(self, run: RunSpec) -> Any:
        if self._device is None:
            spec = self.job.device_spec(run, self.cdir.logs)
            want = int(run.model_hash, 16) if run.model_hash else None
            self._device = self._stack.enter_context(open_device(spec, expected_model_hash=want))
        return self._device

    def drop(self) -> None:
        self._device = None
        try:
            self._stack.close()
        except Exception:  # noqa: BLE001 - see the class docstring
            pass

    def __enter__(self) -> "_Devices":
        return self

    def __exit__(self, *exc: object) -> None:
        self.drop()


def _terminate(signum: int, frame: FrameType | None) -> None:  # noqa: ARG001
    # SIGTERM from the runner (timeout, Ctrl-C): unwind so the device is stopped by the finally blocks.
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m harness.campaign.worker GROUP.json", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, _terminate)
    job = WorkerJob.from_json(Path(args[0]).read_text(encoding="utf-8"))
    failed = run_group(job)
    print(f"{job.runs[0].flight.flight_id}: {len(job.runs) - failed} ok, {failed} failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
