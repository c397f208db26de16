"""DeviceChannel, the one protocol session: it owns the seq (nobody else reads it), sends HELLO once per
session, maps link errors to device errors, and CONFIG + ANCHOR set-up round-trips field by field."""

from __future__ import annotations

import re
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import EstimatorConfig
from harness.device.channel import DeviceChannel, config_message
from harness.device.identity import DeviceIdentity
from harness.errors import DeviceDied, DeviceError, DeviceTimeout, LinkClosed
from harness.flight.data import Anchors
from harness.paths import DEFAULT_FIRMWARE
from protocol import PROTOCOL_VERSION
from protocol import messages as m
from protocol.framing import FrameDecoder, encode_frame

ROOT = Path(__file__).resolve().parents[2]
HELLO_REPLY = dict(proto_version=PROTOCOL_VERSION, fw_major=1, fw_minor=2, fw_patch=3, cost_unit=1, layout_twr=1,
                   layout_tdoa=2, model_hash=0xABC, build_id=b"bid", target=b"mem")


class MemLink:
    """An in-memory 'device': what the channel writes is decoded into `sent`; `answer` decides the reply."""

    name = "mem"

    def __init__(self) -> None:
        self.decoder = FrameDecoder()
        self.sent: list[tuple[int, object]] = []
        self.inbox = bytearray()
        self.closed = False

    def answer(self, seq: int, msg: object) -> bytes:
        if isinstance(msg, m.Hello):
            return encode_frame(m.HelloReply(nonce=msg.nonce, **HELLO_REPLY), 0)
        if isinstance(msg, m.StatsReq):
            return encode_frame(m.Stats(*[0] * len(m.Stats.FIELDS)), 0)
        return b""

    def write(self, data: bytes) -> None:
        if self.closed:
            raise LinkClosed("mem: closed")
        for f in self.decoder.feed(data):
            self.sent.append((f.seq, f.msg))
            self.inbox += self.answer(f.seq, f.msg)

    def read(self, max_bytes: int, timeout: float) -> bytes:
        if self.closed:
            raise LinkClosed("mem: closed")
        out = bytes(self.inbox[:max_bytes])
        del self.inbox[:max_bytes]
        return out


def test_the_channel_owns_the_seq_and_nobody_else_reads_it() -> None:
    link = MemLink()
    ch = DeviceChannel(link)
    ch.hello(timeout=1.0)
    ch.configure(EstimatorConfig(), Anchors(ids=np.array([0, 1]), positions=np.zeros((2, 3))), reset=True)
    first = ch.reserve(5)                              # a whole flight's block, encoded elsewhere
    assert first == 5 and ch.next_seq == 10          # CONFIG 1, ANCHOR 2-3, the STATS_REQ barrier 4
    ch.stats(timeout=1.0)
    assert [seq for seq, _ in link.sent] == [0, 1, 2, 3, 4, 10]
    ch.reserve(0xFFFF - ch.next_seq)
    assert ch.send(m.StatsReq()) == 0xFFFF and ch.next_seq == 0          # wraps at 16 bits
    # no module but the channel touches a private seq counter
    offenders = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "harness").rglob("*.py"))
                 if p.name != "channel.py" and re.search(r"\._seq\b", p.read_text())]
    assert offenders == []


def test_one_hello_gives_the_identity_and_check_does_not_send_another() -> None:
    from harness.device.base import Device

    mem = MemLink()

    class MemDevice(Device):
        name = "mem device"
        link = mem  # type: ignore[assignment]

        def start(self) -> None: ...
        def stop(self) -> int | None: return None
        def alive(self) -> bool: return True

    dev = MemDevice()
    with pytest.raises(DeviceError, match="no HELLO"):
        dev.identity  # noqa: B018
    reply = dev.hello(timeout=1.0)
    dev.check(expected_model_hash=0xABC, expected_layouts=(1, 2))
    assert sum(isinstance(msg, m.Hello) for _, msg in mem.sent) == 1
    ident = dev.identity
    assert isinstance(ident, DeviceIdentity) and ident.reply is reply
    assert ident.as_dict() == {"proto_version": PROTOCOL_VERSION, "firmware": "1.2.3", "build_id": "bid",
                               "target": "mem", "model_hash": "0000000000000abc", "layout_twr": 1,
                               "layout_tdoa": 2, "cost_unit": 1}
    assert dev.describe()["model_hash"] == "0000000000000abc"
    assert ident.properties()["uwb_fw_version"] == "1.2.3" and ident.layouts == (1, 2)


def test_link_errors_become_device_errors() -> None:
    link = MemLink()
    death = DeviceDied("fw exited", exit_code=7, log_tail="boom")
    ch = DeviceChannel(link, died=lambda grace: death)
    link.closed = True
    with pytest.raises(DeviceDied, match="device died while writing: fw exited") as info:
        ch.send(m.StatsReq())
    assert info.value.exit_code == 7 and info.value.log_tail == "boom"
    with pytest.raises(DeviceDied, match="while reading"):
        ch.read(0.0)
    # a drained input with the device gone is a death too, not a timeout
    link.closed = False
    with pytest.raises(DeviceDied):
        ch.recv(0.5)
    # a board we cannot observe: the link error stays a link error, silence a timeout
    quiet = DeviceChannel(MemLink())
    with pytest.raises(DeviceTimeout, match="CLOCK"):
        quiet.clock(3, timeout=0.2)
    quiet.link.closed = True  # type: ignore[attr-defined]
    with pytest.raises(LinkClosed):
        quiet.send(m.StatsReq())


def test_configure_round_trip_and_refusal() -> None:
    link = MemLink()
    ch = DeviceChannel(link)
    cfg = replace(EstimatorConfig(), std_twr=0.2, stages=6).with_init(1.0, -2.0, 0.5)
    anchors = Anchors(ids=np.array([3, 5]), positions=np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, 2.5]]))
    ch.configure(cfg, anchors, reset=False)
    (s0, conf), *sent_anchors, (_, barrier) = link.sent
    assert isinstance(conf, m.Config) and conf.reset == 0 and isinstance(barrier, m.StatsReq)
    sent = asdict(conf)
    for name, value in asdict(cfg).items():
        assert sent[name] == pytest.approx(value, rel=1e-6), name      # f32 on the wire
    assert [(a.anchor_id, a.x, a.y, a.z) for _, a in sent_anchors] == [(3, 1.0, 2.0, 3.0), (5, -1.0, 0.5, 2.5)]
    assert config_message(cfg, True).reset == 1
    ch.configure(cfg, None, reset=True)                          # radio level: no anchors
    assert isinstance(link.sent[-2][1], m.Config) and len(link.sent) == 6
    assert ch.recv(0.0) is None                                  # the barrier's STATS is not left pending

    # a device that refuses the CONFIG: DeviceError; an unrelated reply read meanwhile stays pending
    refusing = MemLink()
    refusing.answer = lambda seq, msg: (encode_frame(m.Error(code=int(m.ErrorCode.BAD_CONFIG), msg_type=m.Config.MSG_ID,
                                                             msg_seq=seq, detail=0), 1)
                                        if isinstance(msg, m.Config) else b"")  # type: ignore[method-assign]
    with pytest.raises(DeviceError, match="refused the setup"):
        DeviceChannel(refusing).configure(replace(cfg, std_twr=0.3), anchors)
    # a refusal that comes late (the device busy, a slow link): still found before the run starts, where
    # the run used to go on with the device's previous configuration and pass
    late = MemLink()
    late.answer = refusing.answer  # type: ignore[method-assign]
    reads = []

    def read_late(max_bytes: int, timeout: float) -> bytes:
        reads.append(timeout)
        return b"" if len(reads) == 1 else MemLink.read(late, max_bytes, timeout)   # nothing yet, then all

    late.read = read_late  # type: ignore[method-assign]
    with pytest.raises(DeviceError, match="refused the setup"):
        DeviceChannel(late).configure(cfg, anchors)
    # a device that never answers the barrier: a timeout naming the request, not a run on an unknown config
    mute = MemLink()
    mute.answer = lambda seq, msg: b""  # type: ignore[method-assign]
    with pytest.raises(DeviceTimeout, match="CONFIG"):
        DeviceChannel(mute).configure(cfg, anchors, timeout=0.2)
    other = MemLink()
    other.inbox += encode_frame(m.Error(code=int(m.ErrorCode.DIVERGED), msg_type=0, msg_seq=999, detail=0), 2)
    ch2 = DeviceChannel(other)
    ch2.configure(cfg, anchors)
    kept = ch2.recv(0.0)
    assert kept is not None and isinstance(kept.msg, m.Error) and kept.msg.msg_seq == 999


def test_bulk_results_and_single_frames_share_one_decoder() -> None:
    """RESULT rows decoded in bulk by read() and one by one by recv() are the scalar decoder's values."""
    res = [m.Result(*[(k + i) % 3 for i, _ in enumerate(m.Result.FIELDS)]) for k in range(4)]
    wire = b"".join(encode_frame(r, 100 + k) for k, r in enumerate(res)) + encode_frame(m.Stats(*[1] * len(m.Stats.FIELDS)), 104)
    link = MemLink()
    link.inbox += wire
    ch = DeviceChannel(link)
    first = ch.recv(0.0)
    assert first is not None and first.seq == 100 and first.msg == res[0]
    rest = [ch.recv(0.0) for _ in range(4)]
    assert [f.msg for f in rest if f is not None] == [*res[1:], m.Stats(*[1] * len(m.Stats.FIELDS))]
    link.inbox += wire
    got = ch.read(0.0)
    assert len(got.results) == 4 and [f.seq for f in got.frames] == [104]
    assert got.results["_seq"].tolist() == [100, 101, 102, 103]
    assert ch.frames_ok == 10 and ch.errors.total() == 0


@pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")
def test_a_run_continues_the_sessions_seqs_without_gaps(tmp_path: Path) -> None:
    """HELLO, then a flight and STATS on the same session: the device sees consecutive seqs (no host-restart
    jump, no gap)."""
    from harness.device.host import HostDevice
    from harness.flight.scenarios import scenario_flight
    from harness.flight.run_config import config_for
    from harness.stream.streamer import Pacing, Streamer

    flight = scenario_flight("hover", mode="twr", duration_s=2.0, seed=1, noise="none")
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        assert dev.channel.next_seq == 1
        run = Streamer(dev).run(flight, config_for(flight), Pacing("windowed", 16))
        sent = dev.channel.next_seq
    assert run.stats is not None and run.stats.seq_gaps == 0
    assert run.stats.frames_ok == sent            # every frame of the session, HELLO included
