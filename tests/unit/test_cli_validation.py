"""Options and inputs the CLI used to accept silently or answer with a traceback: each is now refused with
exit code 2 and one line naming the option (or ends quietly, for a closed stdout pipe); `demo` only offers
what it uses; every option has a help text; a bias network that needs the attitude is not run (or
evaluated) where there is none, nor a network stage on a kind the model has no network for; eval-bias finds the training recordings a model names relative to the data
folder."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness import cli
from harness.biasnet.network import BiasModel, init_network
from harness.paths import DEFAULT_FIRMWARE
from harness.twin.features import LAYOUT_TDOA_POS

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "tests" / "fixtures" / "recordings"
REDUCED = FIX / "const1-fixture-tdoa2.csv"
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


@pytest.mark.parametrize("argv, phrase", [
    (["run", "--baud", "0"], "argument --baud: must be >= 1"),
    (["campaign", "--out", "c", "--baud", "-5"], "argument --baud: must be >= 1"),
    (["run", "--timeout", "-1"], "argument --timeout: must be > 0"),
    (["run", "--timeout", "nan"], "argument --timeout: expected a finite number"),
    (["run", "--duration", "1e9"], "argument --duration: must be > 0 and <= 14400 s, got 1e9"),
    (["run", "--duration", "0"], "argument --duration: must be > 0"),
    (["run", "--window", "0"], "argument --window: must be >= 1"),
    (["run", "--speed", "-2"], "argument --speed: must be >= 0.01"),
    (["run", "--speed", "1e-300"], "argument --speed: must be >= 0.01 and <= 1e+06, got 1e-300"),
    (["run", "--seed", "-1"], "argument --seed: must be >= 0"),
    (["train", "--jitter", "nan"], "argument --jitter: expected a finite number"),       # trained, val nan, exit 0
    (["train", "--time-budget", "-1"], "argument --time-budget: must be > 0 s"),
    (["train", "--duration", "1e9"], "argument --duration: must be > 0 and <= 14400 s"),
    (["eval-bias", "--xi", "-1"], "argument --xi: must be > 0 m"),                      # an empty table, exit 0
    (["fit-std", "--xi", "nan"], "argument --xi: expected a finite number"),
    (["tune", "--flight-above", "nan"], "argument --flight-above: expected a finite number"),
    (["lever-arm", "--flight-above", "nan"], "argument --flight-above: expected a finite number"),
    (["calibrate", "--duration", "1e9"], "argument --duration: must be > 0 and <= 14400 s"),
    (["demo", "--recording", "x.csv"], "unrecognized arguments: --recording x.csv"),
    (["demo", "--mode", "tdoa"], "unrecognized arguments: --mode tdoa"),
])
def test_bad_options_are_refused_at_parse_time(capsys: pytest.CaptureFixture[str], argv: list[str],
                                                phrase: str) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert phrase in err and "Traceback" not in err, err


@pytest.mark.parametrize("argv, phrase", [
    (["--lever-arm", "/nonexistent/lever.json"], "--lever-arm applies to a recorded flight"),
    (["--anchors", "anchors.csv", "--constellation", "2"], "--anchors, --constellation apply to a recorded flight"),
    (["--ignore-crc"], "--ignore-crc applies to a recorded flight"),
    (["--radio-loss", "0.5"], "--radio-loss is the tag's packet loss at radio level: it needs --radio"),
    (["--pacing", "lockstep", "--window", "5"], "--window applies to --pacing windowed, not lockstep"),
    (["--speed", "5"], "--speed applies to --pacing realtime, not windowed"),
    (["--target", "host", "--port", "/dev/ttyS0"], "--target host starts its own device"),   # ran as a board
    (["--port", "/dev/null", "--firmware", "uwb-fw"], "a board on --port runs what it was flashed with"),
    (["--target", "host", "--baud", "9600"], "--baud is the line speed of a board on --port"),
])
def test_options_a_simulated_run_would_ignore_are_refused(capsys: pytest.CaptureFixture[str], argv: list[str],
                                                          phrase: str) -> None:
    """They ran with exit 0 and no effect (a --lever-arm file that does not exist included), or, for --target
    host with a --port, as a board."""
    assert cli.main(["run", "--duration", "1", *argv]) == 2
    err = capsys.readouterr().err
    assert phrase in err and len(err.strip().splitlines()) == 1, err


def test_set_out_of_float32_range_is_a_named_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--set", "std_tdoa=1e39", "--duration", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: std_tdoa = 1e+39 does not fit the device's 32-bit float"), err


def test_every_option_has_a_help_text() -> None:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = [f"{name} {'/'.join(a.option_strings) or a.dest}" for name, p in sub.choices.items()
               for a in p._actions if not isinstance(a, argparse._HelpAction) and not a.help]
    assert missing == []


@needs_fw
def test_closed_stdout_pipe_ends_quietly() -> None:
    proc = subprocess.run(f"{sys.executable} -m harness.cli run --duration 3 --json | true", shell=True, cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr
    out = subprocess.run([sys.executable, "-c", "import subprocess, sys; p = subprocess.Popen([sys.executable, '-m', "
                          "'harness.cli', 'run', '--duration', '3', '--json'], stdout=subprocess.PIPE, "
                          "stderr=subprocess.PIPE); p.stdout.close(); err = p.stderr.read(); "
                          "print(p.wait()); print(err.decode())"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    code, _, err = out.stdout.partition("\n")
    assert code == "141" and err.strip() == "", out.stdout


@needs_fw
def test_demo_offers_only_the_options_it_uses() -> None:
    args = cli.build_parser().parse_args(["demo", "--pacing", "realtime", "--speed", "20", "--duration", "1"])
    assert args.speed == 20.0 and not hasattr(args, "recording") and not hasattr(args, "mode")


# ----------------------------------------------------------------------------- network inputs
@needs_fw
def test_attitude_network_is_refused_on_a_replay_without_attitude(capsys: pytest.CaptureFixture[str]) -> None:
    base = ["run", "--recording", str(REDUCED), "--anchors", str(FIX / "anchors.csv"), "--json"]
    assert cli.main(base) == 2                        # default: the simulated pose network, outlier+nn
    err = capsys.readouterr().err
    assert "takes roll, pitch and yaw" in err and "has no IMU" in err
    assert "--model firmware_sim/models/util_tdoa_pos.npz" in err and "--stages outlier" in err
    assert cli.main([*base, "--force"]) == 0
    assert cli.main([*base, "--stages", "outlier"]) == 0
    capsys.readouterr()
    assert cli.main(["run", "--duration", "3", "--uwb-only"]) == 2   # a simulated flight replayed UWB-only
    err = capsys.readouterr().err
    assert "is replayed with --uwb-only" in err and "--layout pos" in err and "rcv_twr.npz" not in err
    assert cli.main(["run", "--duration", "3"]) == 0                # with its IMU the firmware has the attitude


def _pos_model(trained_on: list[str]) -> BiasModel:
    rng = np.random.default_rng(4)
    net = init_network(LAYOUT_TDOA_POS, np.full(6, -6.0), np.full(6, 6.0), -0.3, 0.3, rng)
    return BiasModel(tdoa=net, name="pos", meta={"tdoa_trained_on": trained_on})


@needs_fw
def test_a_network_stage_on_a_kind_the_model_lacks_is_refused(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A TDoA-only model on TWR measurements with outlier+nn: the firmware would skip the correction and the
    figures of 'outlier+nn' would be outlier's, exit 0. Refused (exit 2) by `run` and `fly`, naming the kind."""
    model = _pos_model([]).save(tmp_path / "tdoa_only.npz")
    assert cli.main(["run", "--mode", "twr", "--duration", "2", "--model", str(model)]) == 2
    assert "has no TWR network" in capsys.readouterr().err
    assert cli.main(["fly", "--mode", "twr", "--mission", "hover", "--hover-s", "1", "--seeds", "1", "--config",
                     "outlier+nn", "--model", str(model), "--quiet"]) == 2
    assert "--config outlier+nn corrects TWR measurements" in capsys.readouterr().err
    assert cli.main(["run", "--mode", "tdoa", "--duration", "2", "--model", str(model)]) == 0


def test_eval_bias_resolves_training_recordings_against_the_data_folder(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    data = tmp_path / "data"
    (data / "util" / "const1").mkdir(parents=True)
    shutil.copy(REDUCED, data / "util" / "const1" / REDUCED.name)
    shutil.copy(FIX / "anchors.csv", data / "util" / "anchors.csv")
    model = _pos_model([f"util/const1/{REDUCED.name}"]).save(tmp_path / "pos.npz")
    argv = ["eval-bias", "--model", str(model), "--recording", str(REDUCED), "--anchors", str(FIX / "anchors.csv"),
            "--json"]
    monkeypatch.setenv("UWB_HIL_DATA", str(tmp_path / "elsewhere"))
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"util/const1/{REDUCED.name}" in err and "--data-dir" in err and str(tmp_path / "elsewhere") in err
    assert cli.main([*argv, "--data-dir", str(data)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["baseline_train"] == [REDUCED.stem] and set(res["methods"]) >= {"network", "pair-constant"}
    monkeypatch.setenv("UWB_HIL_DATA", str(data))                   # the default data folder
    assert cli.main(argv) == 0


def test_eval_bias_of_an_attitude_network_on_a_recording_without_attitude_says_what_to_do(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["eval-bias", "--recording", str(REDUCED), "--anchors", str(FIX / "anchors.csv"),
                     "--train"]) == 2
    err = capsys.readouterr().err
    assert "takes roll, pitch and yaw" in err and "has no attitude truth" in err
    assert "--model firmware_sim/models/util_tdoa_pos.npz" in err and "make models" in err


def test_eval_bias_checks_recordings_and_force_overrides(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mm = tmp_path / "anchors_mm.csv"
    rows = (FIX / "anchors.csv").read_text().splitlines()
    mm.write_text("\n".join([rows[0]] + [",".join(r.split(",")[:2] + [str(1000 * float(v)) for v in r.split(",")[2:]])
                                         for r in rows[1:]]) + "\n")
    model = _pos_model([]).save(tmp_path / "pos.npz")
    argv = ["eval-bias", "--model", str(model), "--recording", str(REDUCED), "--anchors", str(mm), "--train", "--json"]
    assert cli.main(argv) == 2
    assert "looks like millimetres" in capsys.readouterr().err
    # --force skips the check; in millimetres no error is below --xi: said so (it was an empty table, exit 0)
    assert cli.main([*argv, "--force"]) == 2
    err = capsys.readouterr().err
    assert "millimetres" not in err and "nothing to evaluate" in err


def test_eval_bias_with_nothing_to_evaluate_is_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--xi` below every error left n = 0: an empty table, exit 0."""
    model = _pos_model([]).save(tmp_path / "pos.npz")
    argv = ["eval-bias", "--model", str(model), "--recording", str(REDUCED), "--anchors", str(FIX / "anchors.csv")]
    assert cli.main([*argv, "--xi", "1e-12"]) == 2       # the fixture's errors are >= 1e-10 m
    assert "has |error| < --xi 1e-12 m: nothing to evaluate" in capsys.readouterr().err
    assert cli.main([*argv, "--json"]) == 0


def test_the_python_m_tools_refuse_bad_options_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """`python -m harness.robustness --seconds -5` was a ScenarioError traceback (exit 1, its code for 'the
    fault accounting disagrees'); the same mapping of errors to exit codes as uwb-hil."""
    from harness import errors, robustness
    for bad in ("-5", "nan", "0"):
        assert robustness.main(["--seconds", bad]) == 2
        assert "--seconds must be a positive number" in capsys.readouterr().err
    assert errors.exit_code(errors.DeviceTimeout("x")) == 3 and errors.exit_code(errors.LinkClosed("x")) == 3
    assert errors.exit_code(errors.UsageError("x")) == 2 and errors.exit_code(FileNotFoundError("x")) == 2


@pytest.mark.parametrize("out", ["DIR", "/dev/full"])
def test_an_output_file_that_cannot_be_written_is_exit_2_not_a_traceback(
        out: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`fly --out DIR` (likewise range-offset, fit-std, train --out) ended in an IsADirectoryError traceback
    with exit 1, the code of a failed verdict."""
    target = str(tmp_path) if out == "DIR" else out
    if out == "/dev/full" and not Path(out).exists():
        pytest.skip("no /dev/full here")
    code = cli.main(["fly", "--mode", "twr", "--mission", "hover", "--hover-s", "1", "--seeds", "1",
                     "--config", "outlier", "--quiet", "--out", target])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: ") and "Traceback" not in err


@pytest.mark.parametrize("argv", [
    ["export-c", str(ROOT / "firmware_sim" / "models" / "bias_model_default.npz"), "--out", "{out}"],
    ["tune", "--recording", str(REDUCED), "--grid", "std_tdoa=0.1,0.2", "--out", "{out}"],
    ["range-offset", "--recording", str(REDUCED), "--out", "{out}"],
    ["lever-arm", "--recording", str(REDUCED), "--out", "{out}"],
    ["fit-std", "--model", str(ROOT / "firmware_sim" / "models" / "bias_model_default.npz"), "--out", "{out}"],
    ["eval-bias", "--recording", str(REDUCED), "--plot", "{out}"],
    ["fly", "--mode", "twr", "--mission", "hover", "--hover-s", "1", "--seeds", "1", "--out", "{out}"],
    ["campaign", "--no-recorded", "--seeds", "1", "--out", "{out}"],
    ["calibrate", "--out", "{out}"],
    ["run", "--duration", "1", "--log-dir", "{out}"],                  # was exit 3, "cannot start" the device
    ["run", "--duration", "1", "--results", "{out}"],
])
def test_an_output_under_a_file_is_refused_before_any_work(argv: list[str], tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """`--out a_file/x` failed at the end (after the training, grid search or fit) with "[Errno 17] File exists"
    naming the folder; a file where a directory is expected (campaign, calibrate) likewise. Now: exit 2 at
    once, naming the option and the file in the way."""
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = str(blocker) if argv[0] in ("campaign", "calibrate") else str(blocker / "sub" / "x.out")
    assert cli.main([a.replace("{out}", out) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: --") and "a_file is a file, not a directory" in err, err
