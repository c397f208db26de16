# uwb-hil: `make demo` and `make test` work on a fresh clone (they create .venv and build the firmware).
PYTHON  ?= python3
VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed-stamp

.PHONY: all demo test test-c test-py firmware bench protocol clean help
all: firmware

help:
	@echo "make demo      set up, build the firmware, fly TWR + TDoA in three configurations"
	@echo "make test      set up and run every test (C unit tests with sanitizers + pytest)"
	@echo "make bench     speed figures (ratios against baselines measured in the same run)"
	@echo "make firmware  build firmware_sim/build/uwb-fw (+ an ASan/UBSan build)"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e . pytest-timeout
	touch $@

firmware:
	$(MAKE) -C firmware_sim all

protocol: $(STAMP)
	$(PY) -m protocol.generate

demo: $(STAMP) firmware
	$(VENV)/bin/uwb-hil demo

test-c:
	$(MAKE) -C firmware_sim test

test-py: $(STAMP) firmware
	$(PY) -m pytest -q

test: test-c test-py

bench: $(STAMP) firmware
	$(PY) -m harness.bench

clean:
	$(MAKE) -C firmware_sim clean
