"""Campaigns on boards (`uwb-hil campaign --target host --target host`, `--target qemu` twice, `--port`,
`--boards FILE`; harness/campaign/boards.py): the flights are dealt to the boards in parallel, every run
records its board (name, port, HELLO), the report compares the boards, and a board that stops answering
mid-campaign is taken out, its runs completed on the other, and the command exits 3 saying so; so does a
board found dead by the check once every flight is back (its runs stand)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

import harness.campaign.cli as campaign_cli
from harness.campaign.boards import BoardExecutor
from harness.cli import main
from harness.device.board_list import BoardSpec, boards_from_options, load_board_list
from harness.errors import InputError
from harness.paths import DEFAULT_FIRMWARE, DEFAULT_STM32_ELF

pytestmark = [pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)"),
              pytest.mark.timeout(300)]

TINY = ["--modes", "twr", "--trajectories", "circle", "--configs", "none,outlier", "--duration", "11",
        "--no-recorded", "--no-latency-runs", "--timeout", "3"]


def _summaries(root: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted((root / "runs").glob("*.json"))]


def test_two_host_boards_share_the_campaign_and_the_report_compares_them(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "c"
    assert main(["campaign", "--out", str(out), "--seeds", "4", *TINY, "--target", "host", "--target", "host"]) == 0
    runs = _summaries(out)
    assert len(runs) == 8 and all(s["status"] == "ok" for s in runs)
    boards = {s["board"]["name"] for s in runs}
    assert boards == {"host-1", "host-2"}
    for s in runs:          # the board's identity with every run: its port and its HELLO
        assert s["board"]["port"].startswith("/dev/pts/") and s["board"]["hello"]["build_id"] == s["device"]["build_id"]
    executor = json.loads((out / "campaign.json").read_text())["executor"]
    # both boards answered the check after the last flight: one HELLO each, well under a second together
    assert executor["taken_out"] == [] and 0.0 < executor["final_check_s"] < 2.0
    report = json.loads((out / "report.json").read_text())
    compared = report["sections"]["boards"]["boards"]
    assert set(compared) == {"host-1", "host-2"} and sum(b["runs"] for b in compared.values()) == 8
    assert all(0.0 < b["rmse"]["outlier"]["mean"] < 0.2 for b in compared.values())
    assert "host-1" in (out / "report.md").read_text()


def _kill_board_when_running(out: Path, board: str, killed: list[int]) -> None:
    """SIGKILL `board`'s firmware once the campaign has written its first run summary."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            boards = json.loads((out / "campaign.json").read_text())["executor"]["boards"]
        except (OSError, ValueError, KeyError):
            boards = []
        if boards and any((out / "runs").glob("*.json")):
            pid = next(b["pid"] for b in boards if b["name"] == board)
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
            return
        time.sleep(0.05)


def test_a_board_that_dies_is_taken_out_and_its_runs_finish_on_the_other(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "c"
    killed: list[int] = []
    watcher = threading.Thread(target=_kill_board_when_running, args=(out, "host-2", killed), daemon=True)
    watcher.start()
    code = main(["campaign", "--out", str(out), "--seeds", "6", *TINY, "--target", "host", "--target", "host",
                 "--no-report"])
    watcher.join(5)
    err = capsys.readouterr()
    assert killed, "host-2 was never killed"
    assert code == 3, err.err                      # the campaign completed, a board was lost: exit 3
    runs = _summaries(out)
    assert len(runs) == 12 and all(s["status"] == "ok" for s in runs), [s.get("error") for s in runs]
    assert "board host-2 taken out" in err.out and "stopped answering" in err.err
    manifest = json.loads((out / "campaign.json").read_text())
    taken = manifest["executor"]["taken_out"]
    assert [t["board"] for t in taken] == ["host-2"] and "exited" in taken[0]["reason"]
    assert json.loads((out / "verdict.json").read_text())["boards_taken_out"] == taken
    # what host-2 did not finish ran on host-1
    assert sum(1 for s in runs if s["board"]["name"] == "host-1") >= 12 - 4


def test_boards_that_die_after_their_last_flight_are_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Two flights on two boards (one each: both are free when the flights are dealt). Once both flights are
    back (the log line of flight 2/2, before the campaign ends), host-1 is frozen (SIGSTOP: its process lives
    but no HELLO comes back) and host-2 killed: nothing asks either again in the flights, only the check at the
    end. Both are reported as taken out after their last flight, the four runs stand and pass, exit 3."""
    plan_and_run = campaign_cli.plan_and_run

    def run_then_kill(*args: Any, executor: BoardExecutor, log: Any, **kw: Any) -> Any:
        def log_and_kill(line: str) -> None:
            log(line)
            if "(flight 2/2)" in line:
                pids = [b.process.pid for b in executor.boards if b.process is not None]
                os.kill(pids[0], signal.SIGSTOP)
                os.kill(pids[1], signal.SIGKILL)
        return plan_and_run(*args, executor=executor, log=log_and_kill, **kw)

    monkeypatch.setattr(campaign_cli, "plan_and_run", run_then_kill)
    out = tmp_path / "c"
    code = main(["campaign", "--out", str(out), "--seeds", "2", *TINY, "--target", "host", "--target", "host"])
    err = capsys.readouterr()
    assert code == 3, err.err
    runs = _summaries(out)
    assert len(runs) == 4 and all(s["status"] == "ok" for s in runs), [s.get("error") for s in runs]
    assert {s["board"]["name"] for s in runs} == {"host-1", "host-2"}
    assert "verdict: PASS" in err.out and "board host-2 taken out after its last flight (its process exited), " \
        "its runs stand" in err.out
    assert "board host-1 taken out (stopped answering: " in err.err and ") after its last flight" in err.err
    executor = json.loads((out / "campaign.json").read_text())["executor"]
    taken = executor["taken_out"]
    assert [(t["board"], t["moved_runs"], t["after_last_flight"]) for t in taken] == \
        [("host-1", 0, True), ("host-2", 0, True)]
    assert "stopped answering" in taken[0]["reason"] and taken[1]["reason"] == "its process exited"
    assert executor["flights_per_board"] == {"host-1": 1, "host-2": 1}
    assert json.loads((out / "verdict.json").read_text())["boards_taken_out"] == taken
    assert "lost after its last flight: its process exited (its runs stand)" in (out / "report.md").read_text()


def test_board_lists_and_options(tmp_path: Path) -> None:
    f = tmp_path / "boards.yaml"
    f.write_text("- {name: a, port: /dev/ttyACM0}\n- {name: b, serial_number: X1, baud: 921600}\n"
                 "- {target: qemu, firmware: fw.elf}\n")
    a, b, c = load_board_list(f)
    assert a == BoardSpec(name="a", target="serial", port="/dev/ttyACM0")
    assert (b.target, b.serial_number, b.baud) == ("serial", "X1", 921600)
    assert (c.name, c.target, c.firmware) == ("qemu-3", "qemu", (tmp_path / "fw.elf").resolve())
    assert [x.name for x in boards_from_options(["qemu", "qemu"], [])] == ["qemu-1", "qemu-2"]
    assert [x.port for x in boards_from_options([], ["/dev/a", "/dev/b"])] == ["/dev/a", "/dev/b"]
    for bad, why in [("- {name: a, port: p, serial_number: s}\n", "not both"), ("- {tagret: host}\n", "unknown field"),
                     ("- {target: serial}\n", "needs a port"), ("- {name: a}\n- {name: a}\n", "unique"),
                     ("[]\n", "non-empty"), ("- {baud: fast}\n", "baud"),
                     ("- {port: /dev/null, baud: -5}\n", "baud must be >= 1")]:     # was exit 3 at the start
        f.write_text(bad)
        with pytest.raises(InputError, match=why):
            load_board_list(f)
    f.write_bytes(b"\xff\xfe\x00garbage")                 # binary: named, not a UnicodeDecodeError (exit 4)
    with pytest.raises(InputError, match="not a UTF-8 text file"):
        load_board_list(f)
    with pytest.raises(InputError, match="needs --port"):
        boards_from_options(["serial"], [])


def test_bad_board_options_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "--out", str(tmp_path / "c"), *TINY, "--target", "serial"]) == 2
    assert "needs --port" in capsys.readouterr().err
    assert main(["campaign", "--out", str(tmp_path / "c"), *TINY, "--boards", str(tmp_path / "none.yaml")]) == 2


@pytest.mark.skipif(shutil.which("qemu-system-arm") is None or not DEFAULT_STM32_ELF.exists(),
                    reason="QEMU or the STM32 build missing (make stm32 installs the ARM toolchain and QEMU)")
@pytest.mark.slow
def test_two_qemu_boards(tmp_path: Path) -> None:
    out = tmp_path / "q"
    assert main(["campaign", "--out", str(out), "--seeds", "2", *TINY, "--configs", "outlier", "--timeout", "20",
                 "--target", "qemu", "--target", "qemu", "--no-report"]) == 0
    runs = _summaries(out)
    assert len(runs) == 2 and all(s["status"] == "ok" for s in runs)
    assert {s["board"]["name"] for s in runs} == {"qemu-1", "qemu-2"}
    assert all(s["device"]["target"] == "stm32f4" for s in runs)
    executor = json.loads((out / "campaign.json").read_text())["executor"]
    assert executor["taken_out"] == [] and 0.0 < executor["final_check_s"] < 2.0   # both answered at the end


@pytest.mark.skipif(shutil.which("qemu-system-arm") is None or not DEFAULT_STM32_ELF.exists(),
                    reason="QEMU or the STM32 build missing (make stm32 installs the ARM toolchain and QEMU)")
@pytest.mark.slow
def test_a_qemu_board_killed_mid_campaign_finishes_on_the_other(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Two emulated STM32F405 boards; qemu-2's QEMU is SIGKILLed after the first run: every run completes on
    qemu-1 and the exit code (3) says a board was lost. When the kill lands after qemu-2's last flight (both
    boards finish together and qemu-1 takes the last flight), the check after the last flight finds it."""
    out = tmp_path / "q"
    killed: list[int] = []
    watcher = threading.Thread(target=_kill_board_when_running, args=(out, "qemu-2", killed), daemon=True)
    watcher.start()
    code = main(["campaign", "--out", str(out), "--seeds", "3", *TINY, "--configs", "outlier", "--timeout", "20",
                 "--target", "qemu", "--target", "qemu", "--no-report"])
    watcher.join(5)
    err = capsys.readouterr()
    assert killed, "qemu-2 was never killed"
    assert code == 3, err.err
    runs = _summaries(out)
    assert len(runs) == 3 and all(s["status"] == "ok" for s in runs), [s.get("error") for s in runs]
    assert all(s["device"]["target"] == "stm32f4" for s in runs)
    taken = json.loads((out / "campaign.json").read_text())["executor"]["taken_out"]
    assert [t["board"] for t in taken] == ["qemu-2"]
    assert "board qemu-2 taken out" in err.out
