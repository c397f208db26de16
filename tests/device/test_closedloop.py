"""Closed loop (issue 9) through the device: short flights (hover and circle; determinism; an underpowered vehicle;
a device that dies mid-flight) and the `fly` command. The vehicle model, sensors, missions and metrics are
tested without a device in tests/unit/test_closedloop_models.py. The device-side controller has its own C tests
(firmware_sim/tests/test_controller*.c, test_firmware_setpoint.c).

Flight bounds were measured with `uwb-hil fly` (docs/closed-loop.md) and carry a margin; they are figures of
the whole loop (error model + estimator + controller + vehicle), not of timing.
"""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from harness.closedloop.cosim import ClosedLoop, FlightLog, LoopConfig
from harness.closedloop.metrics import flight_metrics
from harness.closedloop.mission import Mission, plan
from harness.closedloop.sensors import SensorConfig
from harness.closedloop.vehicle import VehicleParams
from harness.config import PRESETS, EstimatorConfig
from harness.errors import DeviceDied
from harness.flight.arena import Arena
from harness.flight.measurement_errors import sim_config

ARENA = Arena()

# ---------------------------------------------------------------------------- flights on the device
def _fly(device, mission: Mission, mode: str = "tdoa", preset: str = "outlier+nn", seed: int = 1,  # noqa: ANN001
         vehicle: VehicleParams = VehicleParams(), noise: str = "realistic", **loop_kw) -> FlightLog:  # noqa: ANN003
    pl = plan(mission, ARENA)
    est = EstimatorConfig().with_stages(PRESETS[preset])
    return ClosedLoop(device, LoopConfig(**loop_kw)).fly(pl, est, SensorConfig(mode=mode, noise=noise),
                                                         sim_config("los"), ARENA, vehicle, seed)


@pytest.mark.timeout(120)
def test_hover_takes_off_tracks_and_is_deterministic(uwb_device) -> None:  # noqa: ANN001
    mission = Mission(name="hover", hover_s=4.0)
    a = _fly(uwb_device, mission)
    b = _fly(uwb_device, mission)            # same device, CONFIG reset: the same flight again
    fa = flight_metrics(a)
    assert a.aborted is None and fa["takeoff"]["success"], fa["takeoff"]["reason"]
    assert fa["takeoff"]["t_reach_s"] < 2.0
    assert fa["tracking_rmse"] < 0.13 and fa["estimation_rmse"] < 0.13
    assert fa["max_tilt_deg"] < 10.0
    assert a.statuses["accepted"] > 0.95 * sum(a.statuses.values())
    # lockstep: bit-identical flights
    assert np.array_equal(a.p_true, b.p_true) and np.array_equal(a.p_est, b.p_est)
    assert np.array_equal(a.thrust, b.thrust) and a.statuses == b.statuses
    # it landed and the motors are off at the end
    assert a.p_true[-1, 2] == pytest.approx(0.05) and a.thrust[-1] == 0.0 and not a.ctl_on[-1]


@pytest.mark.timeout(120)
@pytest.mark.parametrize("mode", ["twr", "tdoa"])
def test_circle_is_tracked(uwb_device, mode: str) -> None:  # noqa: ANN001
    log = _fly(uwb_device, Mission(name="circle", laps=0.5), mode=mode)
    fm = flight_metrics(log)
    assert log.aborted is None and fm["takeoff"]["success"], fm["takeoff"]["reason"]
    assert fm["tracking_rmse"] < 0.13 and fm["tracking_max"] < 0.3
    assert fm["estimation_rmse"] < 0.13
    # it really flew the half circle: from (2, 0) to (-2, 0)
    main = (log.t > log.meta["phases"]["t_main1"] - 0.5) & (log.t < log.meta["phases"]["t_main1"])
    assert np.all(np.abs(log.p_true[main, 0] + 2.0) < 0.25)


@pytest.mark.timeout(120)
def test_noiseless_circle_shows_the_control_floor(uwb_device) -> None:  # noqa: ANN001
    """Exact measurements and IMU: what is left is the controller's lag (7 mm in the C test) and the
    estimator's own error; the realistic flights above are dominated by the UWB errors."""
    log = _fly(uwb_device, Mission(name="circle", laps=0.5), preset="outlier", noise="none")
    fm = flight_metrics(log)
    assert fm["takeoff"]["success"] and fm["tracking_rmse"] < 0.015 and fm["estimation_rmse"] < 0.006
    assert log.statuses.get("accepted", 0) == sum(log.statuses.values())


@pytest.mark.timeout(60)
def test_realtime_pacing_holds_flight_speed_and_changes_no_number(uwb_device) -> None:  # noqa: ANN001
    mission = Mission(name="hover", hover_s=0.5, ground_wait_s=0.5, takeoff_s=1.5)
    fast = _fly(uwb_device, mission, mode="twr")
    paced = _fly(uwb_device, mission, mode="twr", pacing="realtime", speed=4.0)
    duration = float(paced.t[-1])
    assert paced.wall_s >= duration / 4.0 * 0.97          # never ahead of the flight clock
    assert np.array_equal(fast.p_true, paced.p_true) and np.array_equal(fast.p_est, paced.p_est)
    assert 0 <= paced.late_controls <= len(paced.t)


@pytest.mark.timeout(60)
def test_an_underpowered_vehicle_fails_the_takeoff_rule(uwb_device) -> None:  # noqa: ANN001
    # worn motors: 4 x 0.079 N against 0.314 N of weight (thrust-to-weight 1.007): at most ~0.07 m/s^2 up
    log = _fly(uwb_device, Mission(name="hover", hover_s=1.0), vehicle=VehicleParams(f_max=0.079))
    fm = flight_metrics(log)
    to = fm["takeoff"]
    assert not to["success"] and "did not reach 0.5 m" in to["reason"], to
    assert fm["control_flags"]["thrust_saturated"] > 100     # the controller asked for more than there was


@pytest.mark.timeout(60)
def test_a_device_dying_mid_flight_raises_not_hangs(uwb_device) -> None:  # noqa: ANN001
    pid = getattr(uwb_device, "pid", None)
    if pid is None:
        pytest.skip("needs the emulator (a process the test can kill)")
    pl = plan(Mission(name="hover", hover_s=2.0), ARENA)

    def kill_at(k: int, n: int) -> None:
        if k >= 300:
            os.kill(pid, signal.SIGKILL)

    with pytest.raises(DeviceDied):
        ClosedLoop(uwb_device, LoopConfig(timeout_s=3.0)).fly(
            pl, EstimatorConfig(), SensorConfig(mode="twr"), sim_config("los"), ARENA, seed=1, progress=kill_at)


def test_fly_set_overrides_the_estimator_of_every_flight(tmp_path, capsys) -> None:  # noqa: ANN001
    import json
    from harness.cli import main
    assert main(["fly", "--set", "std_tdoa=x", "--quiet"]) == 2          # refused before any flight
    assert "not a number" in capsys.readouterr().err
    assert main(["fly", "--set", "stages=1", "--quiet"]) == 2            # stages come from --config
    out = tmp_path / "fly.json"
    code = main(["fly", "--mode", "tdoa", "--mission", "hover", "--hover-s", "1", "--seeds", "1",
                 "--config", "outlier", "--set", "std_tdoa=0.3", "--set", "chi2_tdoa=9", "--quiet", "--out", str(out)])
    assert code == 0
    spec = json.loads(out.read_text())["spec"]
    assert spec["estimator"]["std_tdoa"] == pytest.approx(0.3) and spec["estimator"]["chi2_tdoa"] == pytest.approx(9.0)


def test_fly_criteria_file(tmp_path, capsys) -> None:  # noqa: ANN001
    from harness.cli import main
    bad = tmp_path / "bad.toml"
    bad.write_text("max_rmse = 1.0\nmax_p99_rtt_us = 2000\nmax_lost = 0\n")
    assert main(["fly", "--criteria", str(bad), "--quiet"]) == 2         # refused before any flight
    err = capsys.readouterr().err
    assert "max_lost, max_p99_rtt_us not applicable to uwb-hil fly (it judges: max_rmse)" in err, err
    assert main(["fly", "--criteria", str(tmp_path / "none.toml"), "--quiet"]) == 2
    assert "criteria file not found" in capsys.readouterr().err
    assert main(["fly", "--max-rmse", "-1", "--quiet"]) == 2
    assert "--max-rmse must be a finite number >= 0" in capsys.readouterr().err
    strict = tmp_path / "strict.toml"
    strict.write_text("[criteria]\nmax_rmse = 0.000001\n")
    hover = ["fly", "--mode", "tdoa", "--mission", "hover", "--hover-s", "1", "--seeds", "1", "--config", "outlier",
             "--quiet", "--criteria", str(strict)]
    assert main(hover) == 1
    err = capsys.readouterr().err
    assert "verdict failed: tdoa/hover/outlier:tracking_rmse_max" in err and "> 1e-06" in err, err
    assert main([*hover, "--max-rmse", "100"]) == 0                       # the option wins over the file
