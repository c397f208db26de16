"""A campaign worker's device: one for its runs, a fresh one after a failed run (the broken one stopped, an
error while stopping it ignored), every device stopped at the end; each run's summary says ok or failed."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pytest

from harness.campaign import worker
from harness.campaign.plan import FlightSpec, RunSpec
from harness.campaign.store import CampaignDir


def test_a_failed_run_gets_the_next_one_a_fresh_device(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    events: list[str] = []

    @contextmanager
    def fake_open_device(spec: Any, expected_model_hash: int | None = None) -> Iterator[str]:
        name = f"dev{sum(e.startswith('open') for e in events)}"
        events.append(f"open {name}")
        try:
            yield name
        finally:
            events.append(f"stop {name}")
            if name == "dev0":
                raise OSError("the broken device does not stop cleanly")

    def fake_run_one(job: Any, cdir: Any, run: RunSpec, flight: Any, meta: Any, device: str, started: float) -> None:
        events.append(f"{run.config} on {device}")
        if run.config == "none":
            raise RuntimeError("device confused")
        cdir.summary_path(run.run_id).write_text('{"status": "ok"}')

    flight = FlightSpec(source="sim", mode="twr", trajectory="circle", seed=1000, duration_s=12.0)
    runs = tuple(RunSpec(flight=flight, config=c) for c in ("outlier", "none", "outlier+nn", "robust"))
    monkeypatch.setattr(worker, "open_device", fake_open_device)
    monkeypatch.setattr(worker, "_run_one", fake_run_one)
    failed = worker.run_group(worker.WorkerJob(root=str(tmp_path), runs=runs))
    assert failed == 1
    assert events == ["open dev0", "outlier on dev0", "none on dev0", "stop dev0", "open dev1",
                      "outlier+nn on dev1", "robust on dev1", "stop dev1"]
    cdir = CampaignDir(tmp_path)
    failure = cdir.read_summary(runs[1].run_id)
    assert failure is not None and failure["status"] == "failed" and failure["error"] == "device confused"
    assert all(cdir.read_summary(r.run_id) == {"status": "ok"} for r in runs if r.config != "none")
