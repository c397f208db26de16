"""1 MiB of random bytes and mutated valid frames into the sanitizer build of the firmware: it never crashes
(ASan/UBSan abort the process on any error, which would surface as DeviceDied), STATS accounts for what
it rejected, and valid frames after the garbage are processed."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import MODE_UWB_ONLY, EstimatorConfig
from harness.device.host import HostDevice
from harness.paths import DEFAULT_FIRMWARE
from protocol import encode_frame
from protocol import messages as m

ASAN_FIRMWARE = DEFAULT_FIRMWARE.with_name("uwb-fw-asan")
pytestmark = pytest.mark.skipif(not ASAN_FIRMWARE.exists(), reason=f"{ASAN_FIRMWARE} not built (make firmware)")


REJECTION_COUNTERS = ("crc_errors", "framing_errors", "unknown_types", "bad_lengths", "non_finite", "unknown_anchors",
                      "time_backwards", "bad_configs", "dropped_meas")


def _stats(dev: HostDevice) -> m.Stats:
    ch = dev.channel
    ch.send(m.StatsReq())
    return ch.expect(lambda f: isinstance(f.msg, m.Stats), 10.0, "STATS").msg  # type: ignore[no-any-return]


def _drain(dev: HostDevice) -> None:
    while dev.channel.recv(0.0) is not None:
        pass


def test_a_mebibyte_of_garbage_and_mutated_frames_is_survived_and_accounted(tmp_path: Path) -> None:
    rng = np.random.default_rng(2026)
    with HostDevice(ASAN_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        ch = dev.channel
        for i, pos in enumerate(([0, 0, 0.2], [4, 0, 2.8], [4, 4, 0.2], [0, 4, 2.8])):
            ch.send(m.Anchor(anchor_id=i, x=pos[0], y=pos[1], z=pos[2]))
        before = _stats(dev)
        valid = [encode_frame(m.Twr(t_us=1000 + k, anchor_id=k % 4, range=2.0 + 0.01 * k), 40000 + k)
                 for k in range(64)]
        sent = mutated = 0
        while sent < 1 << 20:
            chunk = bytearray(rng.integers(0, 256, 3000, dtype=np.uint8).tobytes())
            # a valid frame with 1-4 flipped bits, delimited, inside the garbage
            frame = bytearray(valid[int(rng.integers(0, len(valid)))])
            for _ in range(int(rng.integers(1, 5))):
                frame[int(rng.integers(0, len(frame) - 1))] ^= 1 << int(rng.integers(0, 8))
            data = bytes(chunk) + b"\x00" + bytes(frame)
            dev.link.write(data)
            sent += len(data)
            mutated += 1
            _drain(dev)
            assert dev.alive(), "the sanitizer build died on garbage"
        # Valid frames after the garbage: a delimiter resynchronises, then HELLO and a measurement work.
        dev.link.write(b"\x00")
        hello = dev.hello(timeout=10.0)
        assert hello.proto_version == m.PROTOCOL_VERSION
        _drain(dev)
        # UWB-only: no IMU in this test
        ch.send(replace(EstimatorConfig(), mode=MODE_UWB_ONLY).with_init(2.0, 2.0, 1.0).to_message(reset=1))
        _drain(dev)
        seq = ch.send(m.Twr(t_us=10_000_000, anchor_id=0, range=3.0))
        res = ch.expect(lambda f: isinstance(f.msg, m.Result) and f.msg.meas_seq == seq, 10.0, "RESULT")
        assert np.isfinite(res.msg.px)
        after = _stats(dev)
        assert dev.alive()
    rejected = sum(getattr(after, k) - getattr(before, k) for k in REJECTION_COUNTERS)
    # every one of the ~340 bursts ends in a delimiter: at least one rejected frame each
    print(f"sent {sent} B, {mutated} mutated frames, rejected {rejected}, frames_ok {after.frames_ok - before.frames_ok}")
    assert rejected >= mutated
    assert after.frames_ok - before.frames_ok >= 3  # HELLO, CONFIG, TWR (+ this STATS_REQ)
