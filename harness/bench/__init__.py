"""`make bench`: speed figures, each a ratio against a baseline measured in the same run.

host.py (device compute, replay, training, memory; `python -m harness.bench`), memory.py (peak RSS of long
flights), qemu.py (the firmware on the STM32F405 under QEMU; `python -m harness.bench.qemu`), qemu_nn.py
(the network kernels alone), qemu_start.py (QEMU start-up), radio.py (one TDoA3 packet, radio level).
"""
