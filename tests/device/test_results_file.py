"""Results files are safe: a resume cuts a partial last line (and says so) and refuses a file whose replay
differs from its records, or whose flight, configuration or firmware differs (exit 2, file unchanged);
a file is locked while written, so a second run on it fails clearly; an unfinished (resumable) file is
never overwritten without --overwrite; a killed harness loses at most the line being written."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from harness import cli
from harness.paths import DEFAULT_FIRMWARE

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")

ROOT = Path(__file__).resolve().parents[2]
FLIGHT = ["--scenario", "circle", "--mode", "twr", "--duration", "20", "--seed", "3", "--stages", "outlier"]
COMPARED = ("status", "innovation", "px", "py", "pz", "vx", "vy", "vz", "var_x", "var_y", "var_z")


def _rows(path: Path) -> list[dict[str, Any]]:
    return [r for r in map(json.loads, path.read_text().splitlines()) if r["type"] == "result"]


def _result_lines(path: Path) -> int:
    if not path.exists():
        return 0
    return sum(1 for line in path.read_text().splitlines() if line.endswith("}") and '"type": "result"' in line)


@pytest.fixture(scope="module")
def complete(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A complete results file of FLIGHT (windowed)."""
    path = tmp_path_factory.mktemp("ref") / "ref.jsonl"
    assert cli.main(["run", *FLIGHT, "--results", str(path)]) == 0
    return path


def _cut(src: Path, dst: Path, keep: int, partial: bool = True,
         edit: Callable[[list[dict[str, Any]]], None] | None = None) -> Path:
    """The header and the first `keep` results of `src` (optionally edited), plus a partial line."""
    lines = src.read_text().splitlines()
    recs = [json.loads(lines[0])] + [json.loads(x) for x in lines[1:keep + 1]]
    if edit is not None:
        edit(recs)
    text = "\n".join(json.dumps(r) for r in recs) + "\n"
    if partial:
        text += lines[keep + 1][:37]          # the harness was killed while writing this line
    dst.write_text(text)
    return dst


def _resume(path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str, str]:
    rc = cli.main(["run", "--resume", str(path), "--json", *extra])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_resume_after_a_partial_last_line_completes_the_flight_and_says_so(
        tmp_path: Path, complete: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _cut(complete, tmp_path / "p.jsonl", keep=800)
    rc, out, err = _resume(path, capsys)
    assert rc == 0, err
    assert "cut a partial last line (37 bytes" in err
    summary = json.loads(out)
    assert summary["resume"]["resumed_at"] == 800 and summary["resume"]["replay_mismatches"] == 0
    lines = path.read_text().splitlines()
    assert all(json.loads(line) for line in lines)                      # every line is JSON again
    rows, ref = _rows(path), _rows(complete)
    assert [r["index"] for r in rows] == list(range(len(ref)))
    for r, q in zip(rows, ref):
        assert all(r[f] == q[f] for f in COMPARED), r["index"]
    rc, out, err = _resume(path, capsys)                               # and it resumes (to nothing) again
    assert rc == 0 and json.loads(out)["resume"]["appended"] == 0


def _set(k: int, field: str, value: Any) -> Callable[[list[dict[str, Any]]], None]:
    def edit(recs: list[dict[str, Any]]) -> None:
        recs[k][field] = value
    return edit


def _header(**changes: Any) -> Callable[[list[dict[str, Any]]], None]:
    def edit(recs: list[dict[str, Any]]) -> None:
        for dotted, value in changes.items():
            obj = recs[0]
            *parents, leaf = dotted.split("__")
            for p in parents:
                obj = obj[p]
            obj[leaf] = value
    return edit


REFUSED = {
    "edited record": (_set(300, "px", 0.5), "differs from its records at 1 of 800 measurements .*first: measurement "
                                            "299: px replayed"),
    "NaN record": (_set(10, "pz", float("nan")), "differs from its records at 1 of 800 .*measurement 9: pz"),
    "text in a record": (_set(5, "py", "1.0"), r"p.jsonl:6: result field 'py' is '1.0', expected a number"),
    "another flight": (_header(source__seed=4), "records flight 'sim-circle-twr-realistic-s3', its source now gives "
                                               "'sim-circle-twr-realistic-s4'"),
    "another config": (_header(config__std_twr=0.5), "recorded configuration differs .*std_twr 0.5"),
    "another firmware": (_header(device__build_id="0000000"), "recorded with another firmware .*build_id '0000000'"),
    "another model": (_header(device__model_hash="0123456789abcdef"), "model_hash '0123456789abcdef'"),
    # a header edited by hand: the command line's schema and bounds, one line, exit 2 (was a traceback, exit 1;
    # duration 20000 built 4 million measurements before refusing)
    "bogus stages": (_header(source__stages="bogus"), r"p.jsonl:1: header source stages = 'bogus': --stages must "
                                                      "be one of none, outlier"),
    "text duration": (_header(source__duration="abc"), r"header source duration = 'abc': --duration expected a "
                                                       "number, got 'abc'"),
    "huge duration": (_header(source__duration=1e9), r"header source duration = '1000000000.0': --duration must "
                                                     r"be > 0 and <= 14400 s"),
    "long duration": (_header(source__duration=20000), r"header source duration = '20000': --duration must be"),
    "long text": (_header(source__scenario="x" * 10_000), r"header source scenario = 'x{100}'\.\.\.: too long "
                                                          r"\(10000 characters"),
    "switch as text": (_header(source__force="yes"), r"header source force = 'yes': --force is a switch"),
    "set not a list": (_header(source__set="std_twr=1"), r"header source set = 'std_twr=1': not a value --set takes"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_resume_refuses_a_file_it_cannot_continue_and_leaves_it_unchanged(
        tmp_path: Path, complete: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    edit, phrase = REFUSED[case]
    path = _cut(complete, tmp_path / "p.jsonl", keep=800, edit=edit)
    before = path.read_bytes()
    rc, out, err = _resume(path, capsys)
    assert rc == 2 and out == "", err
    assert err.startswith("uwb-hil: error: ") and re.search(phrase, err), err
    assert path.read_bytes() == before


def test_resume_accepts_a_record_within_float_tolerance(tmp_path: Path, complete: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    px = _rows(complete)[300]["px"]
    path = _cut(complete, tmp_path / "p.jsonl", keep=800, edit=_set(301, "px", px * (1 + 1e-7)))
    rc, out, err = _resume(path, capsys)
    assert rc == 0, err


def test_resume_refuses_an_edited_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from harness.flight.native import save_flight
    from harness.flight.scenarios import scenario_flight
    flight = scenario_flight("circle", mode="twr", duration_s=10.0, seed=5)
    rec = save_flight(flight, tmp_path / "flight.npz")
    full = tmp_path / "full.jsonl"
    assert cli.main(["run", "--recording", str(rec), "--stages", "outlier", "--results", str(full)]) == 0
    path = _cut(full, tmp_path / "p.jsonl", keep=500)
    value = flight.uwb.value.copy()
    value[1000] += 0.05                                          # one range edited in place, after the cut
    save_flight(replace(flight, uwb=replace(flight.uwb, value=value)), rec)
    before = path.read_bytes()
    rc, out, err = _resume(path, capsys)
    assert rc == 2 and "the recording was edited or replaced" in err, err
    assert path.read_bytes() == before


def test_resume_refuses_flags_that_conflict_with_the_header(tmp_path: Path, complete: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    path = _cut(complete, tmp_path / "p.jsonl", keep=100)
    rc, _, err = _resume(path, capsys, "--mode", "tdoa", "--duration", "5")
    assert rc == 2 and "drop --mode, --duration" in err, err
    # compared as given or not: a value equal to its default is refused too (issue 27: `--stages outlier+nn`,
    # the default, on an outlier run finished as outlier, exit 0); an abbreviation as well
    before = path.read_bytes()
    for flags, named in ((("--stages", "outlier+nn"), "--stages"), (("--stages=outlier+nn",), "--stages"),
                         (("--stag", "outlier+nn"), "--stages"), (("--seed", "1"), "--seed")):
        rc, _, err = _resume(path, capsys, *flags)
        assert rc == 2 and f"drop {named} " in err, (flags, err)
        assert path.read_bytes() == before
    rc, _, err = _resume(path, capsys, "--timeout", "3")          # device options are fine
    assert rc == 0, err


def test_unfinished_file_is_not_overwritten_without_overwrite(tmp_path: Path, complete: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    path = _cut(complete, tmp_path / "p.jsonl", keep=100)
    before = path.read_bytes()
    assert cli.main(["run", *FLIGHT, "--results", str(path)]) == 2
    err = capsys.readouterr().err
    assert "holds an unfinished run" in err and f"--resume {path}" in err and "--overwrite" in err, err
    assert path.read_bytes() == before
    other = tmp_path / "notes.txt"
    other.write_text("my notes\n")
    assert cli.main(["run", *FLIGHT, "--results", str(other)]) == 2
    assert "not a uwb-hil results file" in capsys.readouterr().err and other.read_text() == "my notes\n"
    assert cli.main(["run", *FLIGHT, "--results", str(path), "--overwrite"]) == 0
    assert len(_rows(path)) == len(_rows(complete))
    assert cli.main(["run", *FLIGHT, "--results", str(path)]) == 0     # a complete run may be replaced


def test_results_file_errors_are_named_not_tracebacks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", *FLIGHT, "--results", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"results file {tmp_path} is a directory" in err and "Traceback" not in err
    if Path("/dev/full").exists():
        assert cli.main(["run", *FLIGHT, "--results", "/dev/full"]) == 2
        err = capsys.readouterr().err
        assert "cannot write results file /dev/full: No space left on device" in err, err


class CliThread(threading.Thread):
    def __init__(self, argv: list[str]) -> None:
        super().__init__(daemon=True)
        self.argv = argv
        self.rc: int | None = None

    def run(self) -> None:
        self.rc = cli.main(self.argv)


def test_a_second_run_on_the_same_file_fails_while_the_first_writes(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.jsonl"
    first = CliThread(["run", *FLIGHT, "--pacing", "realtime", "--speed", "4", "--results", str(path)])
    first.start()
    deadline = time.monotonic() + 30
    while _result_lines(path) < 100:
        assert first.is_alive() and time.monotonic() < deadline, "first run produced no results"
        time.sleep(0.02)
    rc_second = cli.main(["run", *FLIGHT, "--results", str(path)])
    rc_overwrite = cli.main(["run", *FLIGHT, "--results", str(path), "--overwrite"])
    rc_resume = cli.main(["run", "--resume", str(path)])
    err = capsys.readouterr().err
    first.join(60)
    assert rc_second == rc_overwrite == rc_resume == 2
    assert err.count(f"results file {path} is in use by another uwb-hil run") == 3, err
    assert first.rc == 0
    rows = _rows(path)
    assert [r["index"] for r in rows] == list(range(len(rows))) and len(rows) == 3999


def test_a_killed_harness_loses_at_most_the_line_being_written(tmp_path: Path, complete: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "killed.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "harness.cli", "run", *FLIGHT, "--pacing", "realtime",
                             "--speed", "10", "--results", str(path)], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while _result_lines(path) < 300:
            assert proc.poll() is None and time.monotonic() < deadline, "run ended or produced nothing"
            time.sleep(0.01)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)       # the harness and its emulator, mid-run
        proc.wait(10)
    lines = path.read_text().split("\n")
    for line in lines[:-1]:
        json.loads(line)                          # every complete line is intact
    assert lines[-1] == "" or not lines[-1].endswith("}")
    kept = sum(1 for x in lines[:-1] if '"type": "result"' in x)
    assert kept >= 300
    rc, out, err = _resume(path, capsys)
    assert rc == 0, err
    rows, ref = _rows(path), _rows(complete)
    assert len(rows) == len(ref) and all(r[f] == q[f] for r, q in zip(rows, ref) for f in COMPARED)
    assert np.all(np.diff([r["index"] for r in rows]) == 1)


def test_a_long_flight_resumes_in_slices_with_the_plain_runs_results(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Above 120 s a simulated flight is streamed in 30 s slices; its resume rebuilds and replays it slice by
    slice too (harness/stream/resume_sliced.py: the whole flight is never built) and ends with the results
    of the uninterrupted run. The cut falls inside the third slice, which is split there."""
    long = ["--scenario", "circle", "--mode", "twr", "--duration", "125", "--seed", "2", "--stages", "outlier"]
    full = tmp_path / "full.jsonl"
    assert cli.main(["run", *long, "--results", str(full), "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    n = want["measurements"]
    keep = int(n * 0.55)
    path = _cut(full, tmp_path / "p.jsonl", keep=keep)
    rc, out, err = _resume(path, capsys)
    assert rc == 0, err
    got = json.loads(out)
    k0 = got["resume"]["resumed_at"]            # the cut lines include a stats record per slice before it
    assert keep - 5 <= k0 <= keep and got["resume"]["replayed"] == k0 and got["resume"]["appended"] == n - k0
    assert got["accuracy"]["rmse"] == pytest.approx(want["accuracy"]["rmse"], rel=1e-6)
    a, b = _rows(full), _rows(path)
    assert len(a) == len(b) == n
    for k in (0, k0 - 1, k0, n - 1):
        assert b[k]["index"] == k and b[k]["px"] == pytest.approx(a[k]["px"], rel=1e-5, abs=1e-6)
    # an edited recorded row inside a replayed slice is refused, the file unchanged
    bad = _cut(full, tmp_path / "bad.jsonl", keep=keep, edit=_set(200, "px", 3.0))
    before = bad.read_bytes()
    rc, _, err = _resume(bad, capsys)
    assert rc == 2 and "the replay of the recorded part differs from its records" in err, err
    assert bad.read_bytes() == before
