# uwb-hil: `make demo` and `make test` work on a fresh clone (they create .venv and build the firmware).
PYTHON  ?= python3
VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed-stamp

.PHONY: all demo test test-c test-py test-board test-light-install firmware bench protocol clean help
all: firmware

help:
	@echo "make demo      set up, build the firmware, fly TWR + TDoA in three configurations"
	@echo "make test      set up and run every test (C unit tests with sanitizers, bounded fuzzing, pytest, the board and install checks)"
	@echo "make bench     speed figures (ratios against baselines measured in the same run)"
	@echo "make firmware  build firmware_sim/build/uwb-fw (+ an ASan/UBSan build)"
	@echo "make stm32     STM32F405 build for QEMU / a board (installs the ARM toolchain + QEMU if missing)"
	@echo "make size      flash / RAM of the STM32F405 firmware, with the bias network's share"
	@echo "make fuzz      libFuzzer over the frame parser and firmware input path (FUZZ_SECONDS=600)"
	@echo "make longflight  1-hour simulated flight with faults through the firmware"
	@echo "make campaign  the paper's experiments through the firmware + report (CAMPAIGN_DIR, CAMPAIGN_ARGS)"
	@echo "make models    train the shipped bias networks (simulated; UTIL, rcv_twr, uSD logs: \$$UWB_HIL_DATA, else ../shared/data)"
	@echo "make replay-all  every shared recording in every configuration against --max-rmse 2 (docs/verdicts.md)"
	@echo "make real-flights  the estimator on the held-out real Crazyflie flights (docs/real-flights.md)"
	@echo "make test-board  the device tests against one host firmware kept up as a board on a pty"
	@echo "make test-light-install  pip install without extras, and the wheel outside the checkout"

# Extras (pyproject.toml): [train] = PyTorch (uwb-hil train / models, the M4 bench's check), [test] = what
# the test suite adds, [cluster] = Dask distributed (campaign --scheduler), [farm] = labgrid (--labgrid-place).
# constraints.txt pins torch to the CPU build on disk.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -c constraints.txt -e '.[train,test,cluster,farm]'
	touch $@

firmware:
	$(MAKE) -C firmware_sim all

protocol: $(STAMP)
	$(PY) -m protocol.generate

demo: $(STAMP) firmware
	$(VENV)/bin/uwb-hil demo

test-c:
	$(MAKE) -C firmware_sim test

# No root needed: the STM32 build (which may apt-get the ARM toolchain) is not a prerequisite; without the
# toolchain the QEMU tests skip with the reason. `make test` (CI) builds it first, so they run there.
# Same for ser2net (net-tools): `make test` installs it first; without it the RFC 2217 tests skip.
test-py: $(STAMP) firmware
	$(PY) -m pytest -q

# The device tests against ONE host-firmware process kept up for the whole session and reached as a board is
# (its pty path as --uwb-port, target serial): a board on the bench is not restarted between tests, so every
# test compares STATS deltas or resets what it needs through CONFIG (harness/device/pretend_board.py).
# Selected: the tests that use the board (the plugin marks every test requesting uwb_device) and the
# `hardware` ones; the others in tests/device run their own devices, as in test-py (`make test-board
# BOARD_MARK=` runs all of tests/device on the board: about 7 min on 2 shared cores).
BOARD_TESTS ?= tests/device
BOARD_MARK  ?= uwb_device or hardware
test-board: $(STAMP) firmware
	$(PY) -m harness.device.pretend_board -- $(PY) -m pytest -q -p no:cacheprovider --uwb-port {port} \
	    $(if $(BOARD_MARK),-m "$(BOARD_MARK)") $(BOARD_TESTS)

# `pip install -e .` without extras in a fresh virtualenv (no PyTorch): demo and run work, train says how to
# get torch. LIGHT_VENV is rebuilt each time (local wheels: about a minute).
LIGHT_VENV ?= build/light-venv
# Then the wheel (not editable) in a fresh virtualenv outside the checkout: `uwb-hil run` and `demo` build
# the host firmware from the shipped sources into a fresh cache (scripts/check_wheel_install.sh).
test-light-install: firmware
	PYTHON=$(PYTHON) bash scripts/check_light_install.sh $(LIGHT_VENV)
	PYTHON=$(PYTHON) bash scripts/check_wheel_install.sh

# Fuzzing (clang + libFuzzer, installed when missing): `make test` runs a bounded fuzz (TEST_FUZZ_SECONDS
# in total across the targets); `make fuzz FUZZ_SECONDS=600` fuzzes longer. Any crash, leak or
# sanitizer report fails. See docs/robustness.md.
FUZZ_SECONDS      ?= 600
TEST_FUZZ_SECONDS ?= 60
.PHONY: fuzz test-fuzz longflight
fuzz:
	$(MAKE) -C firmware_sim/fuzz run FUZZ_SECONDS=$(FUZZ_SECONDS)

test-fuzz:
	$(MAKE) -C firmware_sim/fuzz run FUZZ_SECONDS=$(TEST_FUZZ_SECONDS)

# The full 1-hour simulated flight through the firmware (NLOS, IMU glitches, UWB outage).
longflight: $(STAMP) firmware
	UWB_LONGFLIGHT_S=3600 $(PY) -m pytest -q -s tests/device/test_long_flight.py --timeout=7200

test: test-c test-fuzz stm32 net-tools chromium test-py test-board test-light-install

bench: $(STAMP) firmware stm32
	$(PY) -m harness.bench
	$(PY) -m harness.bench.qemu
	$(PY) -m harness.bench.qemu_proto --no-build
	$(PY) -m harness.bench.real_replay
	$(PY) -m harness.campaign.bench_cluster

# STM32F405 (Crazyflie MCU) build, run under QEMU by tests/mcu/test_qemu.py and harness/bench/qemu.py
# (docs/qemu.md). The ARM toolchain and QEMU come from Debian when missing: the script runs
# apt-get update + install (root or password-less sudo; UWB_NO_INSTALL=1 only checks).
.PHONY: arm-tools stm32 size net-tools
arm-tools:
	bash scripts/ensure_arm_tools.sh

# ser2net (Debian) serves the host firmware's pty as RFC 2217 for tests/device/test_remote_link.py; when it
# cannot be installed (not root, no apt) those tests are skipped with the reason, `make test` goes on.
net-tools:
	-bash scripts/ensure_ser2net.sh

# Chromium (Debian) opens the campaign report headless in tests/campaign/test_report_browser.py; when it
# cannot be installed those tests are skipped with the reason, `make test` goes on.
.PHONY: chromium
chromium:
	-bash scripts/ensure_chromium.sh

stm32: arm-tools
	$(MAKE) -C firmware_sim/stm32 fw selftest nnbench semihost protobench

size: stm32
	@$(MAKE) -s -C firmware_sim/stm32 size

# The full campaign (not in CI; the open-loop runs resume when re-run): the closed-loop flights first
# (DIR/closed_loop.json, ~7 min, flown again each time), then the paper's runs and the report, which
# includes the closed-loop section: DIR/report.html, report.md, report.json. docs/campaign.md.
CAMPAIGN_DIR  ?= out/campaign
CAMPAIGN_ARGS ?=
FLY_ARGS      ?=
# The networks trained on ../shared/data are not committed: built from it when missing (seeded: the hashes in
# firmware_sim/models/models.json come out again on the machine that wrote it, other CPUs get other weights
# with the same held-out figures; models.json itself is left as committed).
RECORDED_MODELS := firmware_sim/models/util_tdoa_pos.npz firmware_sim/models/rcv_twr.npz \
                   firmware_sim/models/cf_tdoa_pose.npz
firmware_sim/models/util_tdoa_pos.npz: | $(STAMP)
	$(VENV)/bin/uwb-hil models --only util --keep-summary
firmware_sim/models/rcv_twr.npz: | $(STAMP)
	$(VENV)/bin/uwb-hil models --only rcv --keep-summary
firmware_sim/models/cf_tdoa_pose.npz: | $(STAMP)
	$(VENV)/bin/uwb-hil models --only cfusd --keep-summary

# Every shared recording (rcv_twr 1-5, UTIL const1-3) in every configuration through `uwb-hil run
# --max-rmse 2`: each must pass or exit non-zero naming why (docs/verdicts.md; ~5 min on 2 cores).
.PHONY: replay-all
replay-all: $(STAMP) firmware $(RECORDED_MODELS)
	$(PY) -m harness.report.replay_all

.PHONY: campaign
campaign: $(STAMP) firmware $(RECORDED_MODELS)
	mkdir -p $(CAMPAIGN_DIR)
	$(VENV)/bin/uwb-hil fly --out $(CAMPAIGN_DIR)/closed_loop.json $(FLY_ARGS)
	$(VENV)/bin/uwb-hil campaign --out $(CAMPAIGN_DIR) $(CAMPAIGN_ARGS)

clean:
	$(MAKE) -C firmware_sim clean

# The shipped bias networks (firmware_sim/models/): simulated TWR/TDoA (LOS, compiled in; obstacle arena,
# bias_model_nlos.npz), UTIL, rcv_twr and the Crazyflie uSD logs (cf_tdoa_pose.npz); reproducible
# (seeded, single-threaded, ends by early stopping). Rebuild the firmware afterwards: `make firmware`.
.PHONY: models
models: $(STAMP)
	$(VENV)/bin/uwb-hil models
	$(MAKE) firmware

# The estimator on the real Crazyflie flights (../shared/data/cf_usd), held out by flight: UWB-only vs IMU,
# outlier rejection with and without the real-flight network, lever arm calibrated on training flights
# (docs/real-flights.md; ~7 min on 2 cores: every shared log with and without the ToF ranger). The network is built from the shared logs when missing.
.PHONY: real-flights
real-flights: $(STAMP) firmware firmware_sim/models/cf_tdoa_pose.npz
	$(PY) -m harness.report.real_flights
