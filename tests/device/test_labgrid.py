"""A board from a labgrid farm (`--labgrid-place NAME`, harness/device/labgrid.py), end to end on this machine:
a real labgrid coordinator (gRPC) and exporter on the loopback, the exporter serving a pty that the host
firmware answers on (its RawSerialPort becomes a NetworkSerialPort through ser2net). `uwb-hil run` acquires
the place, flies through it and releases it; a second client is refused the place while the first holds it;
the place is released after an error too. Skips with the reason when labgrid or ser2net is missing."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.cli import main
from harness.device.board_process import PtyBoard, stop_process
from harness.device.labgrid import PlaceOptions, place
from harness.errors import DeviceError
from harness.paths import DEFAULT_FIRMWARE

BIN = Path(sys.executable).parent
SER2NET = shutil.which("ser2net") or next((p for p in ("/usr/sbin/ser2net", "/usr/bin/ser2net") if Path(p).exists()),
                                          None)
pytestmark = [pytest.mark.timeout(180),
              pytest.mark.skipif(not (BIN / "labgrid-coordinator").exists(),
                                 reason="labgrid not installed (the [farm] extra; `make` installs it)"),
              pytest.mark.skipif(SER2NET is None, reason="ser2net not installed (scripts/ensure_ser2net.sh)"),
              pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")]

# labgrid's exporter starts ser2net listening on every interface; this wrapper keeps it on the loopback
LOOPBACK_SER2NET = """#!{python}
import os, re, sys
args = [re.sub(r"\\btcp,(\\d+)", r"tcp,127.0.0.1,\\1", a) for a in sys.argv[1:]]
os.execv({real!r}, [{real!r}, *args])
"""


@dataclass
class Farm:
    coordinator: str
    place: str
    tmp: Path

    def client(self, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(BIN / "labgrid-client"), "-x", self.coordinator, "-p", self.place, *args],
                              capture_output=True, text=True, timeout=30, env={**os.environ, **(env or {})})

    def holder(self) -> str:
        out = self.client("show").stdout
        return next((ln.split(":", 1)[1].strip() for ln in out.splitlines() if ln.strip().startswith("acquired:")), "")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(what: str, ready: object, proc: subprocess.Popen[bytes], log: Path, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.skip(f"{what} exited with {proc.returncode}: {log.read_text()[-500:]}")
        if ready():  # type: ignore[operator]
            return
        time.sleep(0.3)
    pytest.skip(f"{what} not ready within {timeout:g} s: {log.read_text()[-500:]}")


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _start(cmd: list[str], log: Path, cwd: Path, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
    return subprocess.Popen(cmd, cwd=cwd, stdout=open(log, "wb"), stderr=subprocess.STDOUT,  # noqa: SIM115
                            stdin=subprocess.DEVNULL, env={**os.environ, **(env or {})}, start_new_session=True)


@pytest.fixture(scope="module")
def farm(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Farm]:
    tmp = tmp_path_factory.mktemp("labgrid")
    wrapper_dir = tmp / "bin"
    wrapper_dir.mkdir()
    (wrapper_dir / "ser2net").write_text(LOOPBACK_SER2NET.format(python=sys.executable, real=SER2NET))
    (wrapper_dir / "ser2net").chmod(0o755)
    port = _free_port()
    address = f"127.0.0.1:{port}"
    procs: list[subprocess.Popen[bytes]] = []
    with PtyBoard(DEFAULT_FIRMWARE, tmp / "board.log") as board:
        try:
            coord = _start([str(BIN / "labgrid-coordinator"), "-l", address], tmp / "coordinator.log", tmp)
            procs.append(coord)
            _wait("labgrid-coordinator", lambda: _listening(port), coord, tmp / "coordinator.log")
            (tmp / "exporter.yaml").write_text(f"uwb:\n  RawSerialPort:\n    port: {board.port}\n    speed: 115200\n")
            exp = _start([str(BIN / "labgrid-exporter"), "-c", address, "-n", "uwbexp", "--hostname", "127.0.0.1",
                          str(tmp / "exporter.yaml")], tmp / "exporter.log", tmp,
                         env={"PATH": f"{wrapper_dir}:{os.environ.get('PATH', '')}"})
            procs.append(exp)
            farm = Farm(address, "bench", tmp)
            _wait("labgrid-exporter", lambda: "uwbexp/uwb/NetworkSerialPort" in farm.client("resources").stdout,
                  exp, tmp / "exporter.log")
            assert farm.client("create").returncode == 0
            assert farm.client("add-match", "uwbexp/uwb/NetworkSerialPort").returncode == 0
            yield farm
        finally:
            for proc in reversed(procs):
                stop_process(proc, 10.0)


def test_run_a_flight_on_a_labgrid_place_and_release_it(farm: Farm, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--labgrid-place", farm.place, "--labgrid-coordinator", farm.coordinator,
                 "--duration", "6", "--timeout", "10", "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert '"rmse"' in out.out
    assert farm.holder() in ("", "None"), farm.client("show").stdout      # released


def test_a_second_client_is_refused_while_the_first_holds_it(farm: Farm, monkeypatch: pytest.MonkeyPatch) -> None:
    opts = PlaceOptions(name=farm.place, coordinator=farm.coordinator)
    with place(opts) as lease:
        assert lease.url.startswith("rfc2217://127.0.0.1:")
        ours = farm.holder()
        assert ours.endswith("/" + os.environ.get("LG_USERNAME", __import__("getpass").getuser()))
        other = farm.client("acquire", env={"LG_HOSTNAME": "other-host", "LG_USERNAME": "other"})
        assert other.returncode != 0 and "already acquired" in other.stderr
        with monkeypatch.context() as m:       # our own client, as another user: refused, exit 3's error
            m.setenv("LG_HOSTNAME", "other-host")
            m.setenv("LG_USERNAME", "other")
            with pytest.raises(DeviceError, match="already acquired"):
                with place(opts):
                    pass
        assert farm.holder() == ours        # the refused client did not release ours
    assert farm.holder() in ("", "None")


def test_the_place_is_released_after_an_error(farm: Farm) -> None:
    with pytest.raises(RuntimeError, match="boom"):
        with place(PlaceOptions(name=farm.place, coordinator=farm.coordinator)):
            assert farm.holder() not in ("", "None")
            raise RuntimeError("boom")
    assert farm.holder() in ("", "None")


def test_campaign_on_a_labgrid_place(farm: Farm, tmp_path: Path) -> None:
    import json
    assert main(["campaign", "--out", str(tmp_path / "c"), "--seeds", "1", "--modes", "twr", "--trajectories", "circle",
                 "--configs", "outlier", "--duration", "11", "--no-recorded", "--no-latency-runs", "--no-report",
                 "--labgrid-place", farm.place, "--labgrid-coordinator", farm.coordinator]) == 0
    summary = json.loads((tmp_path / "c" / "runs" / "sim-twr-circle-s1000-outlier.json").read_text())
    assert summary["status"] == "ok" and summary["board"]["port"].startswith("rfc2217://127.0.0.1:")
    assert farm.holder() in ("", "None")


pytest_plugins = ["pytester"]


def test_pytest_plugin_holds_the_place_for_the_session(farm: Farm, pytester: pytest.Pytester) -> None:
    pytester.makepyfile(f"""
        def test_dev(uwb_device, uwb_port):
            assert uwb_port.startswith("rfc2217://127.0.0.1:")
            assert uwb_device.identity.build_id
            print("HOLDER", {farm.coordinator!r})
    """)
    result = pytester.runpytest("-p", "no:cacheprovider", "-s", "--uwb-labgrid-place", farm.place,
                                "--uwb-labgrid-coordinator", farm.coordinator)
    result.assert_outcomes(passed=1)
    assert farm.holder() in ("", "None")          # released by pytest_unconfigure
    farm.client("acquire", env={"LG_HOSTNAME": "other-host", "LG_USERNAME": "other"})
    try:                                           # held by someone else: the session cannot start
        result = pytester.runpytest("-p", "no:cacheprovider", "--uwb-labgrid-place", farm.place,
                                    "--uwb-labgrid-coordinator", farm.coordinator)
        assert result.ret == pytest.ExitCode.USAGE_ERROR
        result.stderr.fnmatch_lines(["*already acquired*"])
    finally:
        farm.client("release", env={"LG_HOSTNAME": "other-host", "LG_USERNAME": "other"})
