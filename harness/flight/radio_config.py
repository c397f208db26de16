"""Options of the LPS radio simulator (harness/flight/radio_sim.py) and its error. Their own module so that
the simulator and the packet assembly (radio_assemble.py) both depend on them without depending on each other."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.errors import InputError

PROTOCOLS = ("tdoa2", "tdoa3")


class RadioSimError(InputError):
    """A radio simulation was asked for something it cannot produce (ids, options)."""


@dataclass(frozen=True)
class RadioConfig:
    protocol: str = "tdoa2"
    seed: int = 1
    max_ppm: float = 10.0            # clock skews drawn uniformly within +-max_ppm (and kept there)
    walk_ppm: float = 0.02           # random walk of each skew [ppm / sqrt(s)]
    rx_noise_m: float = 0.0          # extra white noise on every RX timestamp [m]
    tx_noise_m: float = 0.0          # jitter of the actual emission around the scheduled TX stamp [m]
    tof_noise_m: float = 0.0         # noise of the anchors' ToF estimates [m]
    antenna_delay_ticks: float = 32951.0
    loss: float = 0.0                # probability that the tag misses a packet
    anchor_loss: float = 0.0         # probability that an anchor misses another's packet
    reboots: tuple[tuple[int, float], ...] = ()   # (anchor id, time since flight start [s])
    reboot_gap_s: float = 0.2        # silence of a rebooting anchor
    reboot_tof_s: float = 0.5        # after it, ToFs of the rebooted anchor unknown this long
    tdoa3_system_hz: float = 400.0
    tdoa3_delay_s: float = 0.005     # +- random TX delay (TDoA3)
    tdoa3_validity_s: float = 0.05   # an anchor reports others heard this recently (TDoA3)
    airtime_s: float = 0.3e-3        # transmissions closer than this collide: nobody receives either
    lpp: bool = True                 # append the LPP position to every packet
    # Share of the error model's white TDoA noise variance (tdoa_std^2) on the tag's two receptions of a
    # difference; the rest goes on the sender's RX stamp of the reference's packet (rxAr_by_An, one per
    # measurement). In the recorded UTIL TDoA flights two measurements that share a tag reception correlate
    # at -0.13 to -0.24 (median TDoA2 -0.20, TDoA3 -0.16; -0.5 if all the noise were the tag's); 0.45 gives
    # the simulated TDoA2 flights' radio level -0.20 (`python -m harness.radio_compare --noise-split`).
    # 1.0 (all on the tag) made the clock-correction candidates 1.5 x as noisy: 7.5 % clock_unreliable drops.
    tag_noise_share: float = 0.45
    # Also keep every received packet with its timestamps unrounded (RadioStream.exact; analysis only: the
    # wire carries whole DW1000 ticks). The engine twin run on them has no tick quantisation, so what is
    # left of its error is the clock correction's (and the tag's motion).
    exact_stamps: bool = False

    def validate(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise RadioSimError(f"radio protocol must be one of {PROTOCOLS}, got {self.protocol!r}")
        for name in ("max_ppm", "walk_ppm", "rx_noise_m", "tx_noise_m", "tof_noise_m", "antenna_delay_ticks"):
            if not (getattr(self, name) >= 0 and np.isfinite(getattr(self, name))):
                raise RadioSimError(f"{name} must be finite and >= 0")
        if self.max_ppm > 20.0:
            raise RadioSimError("max_ppm beyond 20 ppm: outside the DW1000 crystal specification the engine accepts")
        if not 0.0 <= self.tag_noise_share <= 1.0:
            raise RadioSimError("tag_noise_share must be in [0, 1]")
        if not (0 <= self.loss < 1 and 0 <= self.anchor_loss < 1):
            raise RadioSimError("loss probabilities must be in [0, 1)")
