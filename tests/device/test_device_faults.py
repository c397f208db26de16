"""Device faults through the CLI: the emulator is killed (SIGKILL) or hung (SIGSTOP) mid-run. The harness
raises a clear error within a bounded time, keeps every result received in the JSONL file, and
`uwb-hil run --resume FILE` continues the run on a fresh device: the whole-flight results equal those of
an uninterrupted run (the replayed prefix rebuilds the exact filter state)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from harness import cli
from harness.paths import DEFAULT_FIRMWARE
from harness.stream.resume import ResumeError, read_results, split_flight
from harness.stream.streamer import OUTCOME_RESULT

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")

FLIGHT = ["--scenario", "circle", "--mode", "twr", "--duration", "20", "--seed", "3", "--stages", "outlier"]
COMPARED = ("status", "innovation", "px", "py", "pz", "vx", "vy", "vz", "var_x", "var_y", "var_z")


def _children_running(binary: Path) -> list[int]:
    """PIDs of our own child processes running `binary` (the CLI's emulator)."""
    me = os.getpid()
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as fh:
                stat = fh.read().decode(errors="replace")
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as fh:
                cmd = fh.read().split(b"\x00")
        except (OSError, ValueError, IndexError):
            continue
        if ppid == me and cmd and cmd[0].decode(errors="replace") == str(binary):
            out.append(int(entry))
    return out


def _result_lines(path: Path) -> int:
    if not path.exists():
        return 0
    return sum(1 for line in path.read_text().splitlines() if line.endswith("}") and '"type": "result"' in line)


class CliThread(threading.Thread):
    def __init__(self, argv: list[str]) -> None:
        super().__init__(daemon=True)
        self.argv = argv
        self.rc: int | None = None
        self.t_end = 0.0

    def run(self) -> None:
        self.rc = cli.main(self.argv)
        self.t_end = time.monotonic()


def _start_and_wait(argv: list[str], path: Path, min_results: int) -> tuple[CliThread, int]:
    th = CliThread(argv)
    th.start()
    deadline = time.monotonic() + 60
    while _result_lines(path) < min_results:
        assert th.is_alive(), f"run ended early (rc {th.rc})"
        assert time.monotonic() < deadline, "run did not produce results"
        time.sleep(0.02)
    pids = _children_running(DEFAULT_FIRMWARE)
    assert len(pids) == 1, pids
    return th, pids[0]


def _rows(path: Path) -> list[dict[str, Any]]:
    return [r for r in map(json.loads, path.read_text().splitlines()) if r["type"] == "result"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    """The same flight, uninterrupted (windowed: the estimates do not depend on pacing)."""
    path = tmp_path_factory.mktemp("ref") / "ref.jsonl"
    assert cli.main(["run", *FLIGHT, "--results", str(path), "--json"]) == 0
    return _rows(path)


def test_kill_mid_run_is_reported_fast_and_resume_completes_the_flight(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], reference: list[dict[str, Any]]) -> None:
    path = tmp_path / "run.jsonl"
    argv = ["run", *FLIGHT, "--pacing", "realtime", "--speed", "8", "--results", str(path), "--timeout", "2",
            "--log-dir", str(tmp_path), "--json"]
    th, pid = _start_and_wait(argv, path, min_results=600)
    t_kill = time.monotonic()
    os.kill(pid, signal.SIGKILL)
    th.join(10)
    assert not th.is_alive() and th.rc == 3      # exit 3: device or link failure
    assert th.t_end - t_kill < 2.0, f"death noticed after {th.t_end - t_kill:.2f} s"
    noticed_s = th.t_end - t_kill
    assert "died" in capsys.readouterr().err
    kept = _rows(path)
    n = len(reference)
    assert 600 <= len(kept) < n
    assert [r["index"] for r in kept] == list(range(len(kept)))
    assert all(r["outcome"] == OUTCOME_RESULT for r in kept)        # nothing answered was thrown away

    # resume on a fresh device: replays the kept part, appends the rest
    assert cli.main(["run", "--resume", str(path), "--json", "--log-dir", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["resume"]["resumed_at"] == len(kept)
    assert summary["resume"]["replay_mismatches"] == 0
    assert summary["resume"]["appended"] == n - len(kept)
    assert summary["measurements"] == n and summary["results"] == n and summary["lost"] == 0
    figures = (f"SIGKILL -> DeviceDied after {noticed_s:.3f} s; killed after {len(kept)} of {n} results; resume "
               f"replayed {summary['resume']['replayed']} ({summary['resume']['replay_mismatches']} mismatches) in "
               f"{summary['resume'].get('replay_s')} s, appended {summary['resume']['appended']}")
    rows = _rows(path)
    assert [r["index"] for r in rows] == list(range(n))
    for r, q in zip(rows, reference):
        for f in COMPARED:
            assert r[f] == q[f], (r["index"], f)
    # a complete file resumes to nothing
    assert cli.main(["run", "--resume", str(path), "--json", "--log-dir", str(tmp_path)]) == 0
    assert json.loads(capsys.readouterr().out)["resume"]["appended"] == 0
    with capsys.disabled():
        print("\n" + figures)


@pytest.mark.parametrize("pacing", ["windowed", "realtime"])
def test_hung_device_raises_a_timeout_and_keeps_results(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        pacing: str) -> None:
    path = tmp_path / "hang.jsonl"
    extra = ["--window", "8"] if pacing == "windowed" else ["--speed", "4"]
    argv = ["run", *FLIGHT, "--pacing", pacing, *extra, "--results", str(path), "--timeout", "1",
            "--log-dir", str(tmp_path)]
    th, pid = _start_and_wait(argv, path, min_results=200)
    t_stop = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    try:
        th.join(15)
        assert not th.is_alive() and th.rc == 3  # exit 3: device or link failure
        # windowed: 1 s of silence + a 1 s STATS probe (+ 1 s SIGTERM grace in stop); realtime: the 5 s write timeout
        limit = 6.0 if pacing == "windowed" else 10.0
        assert th.t_end - t_stop < limit, f"hang noticed after {th.t_end - t_stop:.2f} s"
        noticed_s = th.t_end - t_stop
    finally:
        if pid in _children_running(DEFAULT_FIRMWARE):   # the CLI's stop() normally killed it already
            os.kill(pid, signal.SIGKILL)
    err = capsys.readouterr().err
    assert ("device silent for 1.0 s" if pacing == "windowed" else "the device stopped reading") in err, err
    rows = _rows(path)
    assert len(rows) >= 200 and [r["index"] for r in rows] == list(range(len(rows)))
    with capsys.disabled():
        print(f"\nSIGSTOP ({pacing}) -> error after {noticed_s:.3f} s, {len(rows)} results kept")


def test_resume_refuses_bad_files(tmp_path: Path) -> None:
    missing = tmp_path / "missing.jsonl"
    with pytest.raises(FileNotFoundError, match="missing.jsonl"):
        read_results(missing)
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"type": "header", "flight": "f", "config": {}, "pacing": {}, "n_measurements": 3}\n'
                   "not json\n{}\n")
    with pytest.raises(ResumeError, match=r"bad.jsonl:2: not JSON"):
        read_results(bad)
    gap = tmp_path / "gap.jsonl"
    gap.write_text('{"type": "header", "flight": "f", "config": {}, "pacing": {}, "n_measurements": 3}\n'
                   '{"type": "result", "index": 1}\n')
    with pytest.raises(ResumeError, match=r"gap.jsonl:2: result field"):
        read_results(gap)
    nohdr = tmp_path / "nohdr.jsonl"
    nohdr.write_text('{"type": "result", "index": 0}\n')
    with pytest.raises(ResumeError, match=r"nohdr.jsonl:1: the first line must be the run header"):
        read_results(nohdr)
    assert cli.main(["run", "--resume", str(bad)]) == 2


def test_partial_last_line_is_ignored(tmp_path: Path) -> None:
    path = tmp_path / "p.jsonl"
    assert cli.main(["run", *FLIGHT[:5], "5", *FLIGHT[6:], "--results", str(path)]) == 0
    text = path.read_text().splitlines()
    rows = [line for line in text if '"type": "result"' in line]
    cut = "\n".join(text[:1] + rows[:100]) + "\n" + rows[100][:40]     # killed while writing line 101
    path.write_text(cut)
    rec = read_results(path)
    assert rec.ignored_partial_line and rec.next_index == 100


def test_split_flight_rebuilds_the_exact_stream() -> None:
    from harness.flight.scenarios import scenario_flight
    from harness.stream.prepare import prepare
    flight = scenario_flight("circle", mode="tdoa", duration_s=3.0, seed=2, noise="gaussian")
    whole = prepare(flight, 0)
    for k0 in (1, 17, len(flight.uwb) - 1):
        a, b = split_flight(flight, k0)
        assert a is not None and b is not None
        pa = prepare(a, 0)
        pb = prepare(b, pa.next_seq)
        assert pa.stream + pb.stream == whole.stream
        assert np.array_equal(np.concatenate([pa.meas_seq, pb.meas_seq]), whole.meas_seq)
