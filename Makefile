# uwbcal: top-level entry points. `make test` and `make demo` work on a fresh machine.
SHELL := bash
.DEFAULT_GOAL := help
VENV ?= .venv
PY := $(VENV)/bin/python
BUILD := build
# scenario of `make demo` (file or example name, e.g. asil_fitted: fitted by `uwbcal gap`)
DEMO_SCENARIO ?= two_stations
CC := cc
VERSION := $(shell cat VERSION)
GIT_HASH := $(shell git rev-parse --short=12 HEAD 2>/dev/null || echo unknown)

CSTD := -std=c11 -D_DEFAULT_SOURCE
CWARN := -Wall -Wextra -Werror -Wshadow -Wpointer-arith -Wstrict-prototypes -Wmissing-prototypes
CVER := -DUWBCAL_FW_VERSION=\"$(VERSION)\" -DUWBCAL_GIT_HASH=\"$(GIT_HASH)\"
CINC := -Ifirmware -Ifirmware/core -Ifirmware/dw1000
SAN := -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer

FW_SRC := $(sort $(wildcard firmware/core/*.c) $(wildcard firmware/dw1000/*.c))
NATIVE_SRC := $(sort $(wildcard firmware/boards/native/*.c))
NATIVE_LIB_SRC := $(filter-out firmware/boards/native/main.c,$(NATIVE_SRC))
FW_HDR := $(wildcard firmware/*/*.h firmware/boards/*/*.h)
CTEST_SRC := $(sort $(wildcard tests/firmware/test_*.c))
CTEST_SUPPORT := $(sort $(wildcard tests/firmware/support/*.c))
CTEST_BIN := $(patsubst tests/firmware/%.c,$(BUILD)/ctest/%,$(CTEST_SRC))
# The EVK1000 USB link's headers, for test_usb_cdc.c (its sources are tested against fakes).
CTEST_INC := -Ifirmware/boards/evk1000 -Ifirmware/boards/evk1000/usb

.PHONY: help venv native firmware ctest lint gen gen-check pytest test demo demo-full newcomer bench clean fuzz fuzz-short

help:
	@echo "make demo      run the main job on simulated stations"
	@echo "make demo-full every README command of the main job, with its full parameters"
	@echo "make test      set up everything and run every test (C, Python, lint, both firmware builds)"
	@echo "make firmware  build the EVK1000 image (.elf .bin .hex) and print its size"
	@echo "make bench     run the benchmarks and print their figures"
	@echo "make fuzz      libFuzzer over frame decode + dispatch (FUZZ_SECONDS=600), execs/s and coverage per file"

venv: $(VENV)/.uwbcal-installed
$(VENV)/.uwbcal-installed: pyproject.toml tools/bootstrap.sh
	VENV=$(VENV) tools/bootstrap.sh

# --- native station (the firmware as a host process) ---------------------------------
# Two builds: -O2 for demos and benchmarks, and ASan+UBSan for the tests.
native: $(BUILD)/native/uwbcal-station $(BUILD)/native-asan/uwbcal-station
# Rebuild the stations when the version flags change (the git hash is baked into GET_INFO).
$(BUILD)/native-flags.txt: FORCE_NATIVE_FLAGS
	@mkdir -p $(@D)
	@echo '$(CVER)' | cmp -s - $@ || echo '$(CVER)' > $@
.PHONY: FORCE_NATIVE_FLAGS
FORCE_NATIVE_FLAGS:
$(BUILD)/native/uwbcal-station: $(FW_SRC) $(NATIVE_SRC) $(FW_HDR) VERSION $(BUILD)/native-flags.txt
	@mkdir -p $(@D)
	$(CC) $(CSTD) $(CWARN) $(CVER) $(CINC) -O2 -g -o $@ $(FW_SRC) $(NATIVE_SRC) -lm
$(BUILD)/native-asan/uwbcal-station: $(FW_SRC) $(NATIVE_SRC) $(FW_HDR) VERSION $(BUILD)/native-flags.txt
	@mkdir -p $(@D)
	$(CC) $(CSTD) $(CWARN) $(CVER) $(CINC) -O1 -g $(SAN) -o $@ $(FW_SRC) $(NATIVE_SRC) -lm

# --- C unit tests, under AddressSanitizer and UBSan -----------------------------------
$(BUILD)/ctest/%: tests/firmware/%.c $(CTEST_SUPPORT) $(FW_SRC) $(NATIVE_LIB_SRC) $(FW_HDR) $(wildcard tests/firmware/*.h tests/firmware/support/*.h firmware/boards/evk1000/usb/*.[ch])
	@mkdir -p $(@D)
	$(CC) $(CSTD) $(CWARN) $(CVER) $(CINC) -Itests/firmware -Itests/firmware/support $(CTEST_INC) -O1 -g $(SAN) \
	  -o $@ $< $(CTEST_SUPPORT) $(FW_SRC) $(NATIVE_LIB_SRC) -lm
ctest: $(CTEST_BIN)
	@set -e; for t in $(abspath $(CTEST_BIN)); do echo "== $$t"; (cd tests/firmware && $$t); done

# --- fuzzing (clang's libFuzzer): frame decode + dispatch with the fake DW1000 and RAM flash --
# `make fuzz` installs clang through tools/bootstrap.sh when it is missing, runs FUZZ_SECONDS,
# then replays the corpus on a coverage build and prints line coverage per firmware file.
# `make test` runs FUZZ_SHORT_SECONDS of it (installing clang the same way), or says it is skipped
# when clang cannot be had.
FUZZ_SECONDS ?= 600
FUZZ_SHORT_SECONDS ?= 20
FUZZ_CC ?= clang
FUZZ := $(BUILD)/fuzz
FUZZ_SRC := tests/fuzz/fuzz_station.c $(FW_SRC) $(NATIVE_LIB_SRC)
FUZZ_DEPS := $(FUZZ_SRC) $(FW_HDR) tests/firmware/fake_spi.c tests/firmware/fake_spi.h
FUZZ_FLAGS := $(CSTD) $(CWARN) $(CVER) $(CINC) -Itests/firmware -g
$(FUZZ)/fuzz_station: $(FUZZ_DEPS)
	@mkdir -p $(@D)
	$(FUZZ_CC) $(FUZZ_FLAGS) -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all \
	  -o $@ $(FUZZ_SRC) -lm
$(FUZZ)/fuzz_station_cov: $(FUZZ_DEPS)
	@mkdir -p $(@D)
	$(FUZZ_CC) $(FUZZ_FLAGS) -O0 -fsanitize=fuzzer -fprofile-instr-generate -fcoverage-mapping \
	  -o $@ $(FUZZ_SRC) -lm
$(FUZZ)/seed/.done: protocol/vectors.json tools/fuzz_corpus.py $(wildcard protocol/messages/*.toml) | venv
	rm -rf $(FUZZ)/seed && $(PY) tools/fuzz_corpus.py $(FUZZ)/seed && touch $@
fuzz: venv
	VENV=$(VENV) tools/bootstrap.sh --fuzz
	$(MAKE) --no-print-directory $(FUZZ)/fuzz_station $(FUZZ)/fuzz_station_cov $(FUZZ)/seed/.done
	$(PY) tools/fuzz_run.py --seconds $(FUZZ_SECONDS) --build $(FUZZ) --coverage
# make test installs clang too (as root with apt, as CI is); where it cannot, the run is skipped
# with the reason instead of failing the whole suite.
fuzz-short: venv
	@command -v $(FUZZ_CC) >/dev/null 2>&1 || VENV=$(VENV) tools/bootstrap.sh --fuzz || true
	@if command -v $(FUZZ_CC) >/dev/null 2>&1; then \
	  $(MAKE) --no-print-directory $(FUZZ)/fuzz_station $(FUZZ)/seed/.done && \
	  $(PY) tools/fuzz_run.py --seconds $(FUZZ_SHORT_SECONDS) --build $(FUZZ); \
	else echo "fuzz: skipped: $(FUZZ_CC) not installed (make fuzz installs it, or apt-get install clang)"; fi

# --- EVK1000 image (arm-none-eabi) ------------------------------------------------------
include firmware/boards/evk1000/board.mk

# --- protocol code generation -----------------------------------------------------------
gen: venv
	$(PY) tools/gen_protocol.py
gen-check: venv
	$(PY) tools/gen_protocol.py --check

# --- Python -----------------------------------------------------------------------------
lint: venv
	$(VENV)/bin/ruff check host tests tools
	$(VENV)/bin/mypy

pytest: venv native usbhosted
	UWBCAL_STATION=$(abspath $(BUILD)/native-asan/uwbcal-station) $(PY) -m pytest

newcomer: venv $(BUILD)/native/uwbcal-station
	UWBCAL_STATION=$(abspath $(BUILD)/native/uwbcal-station) $(PY) tools/newcomer.py --short

test: venv gen-check ctest fuzz-short firmware lint pytest newcomer
	@echo "make test: all passed"

demo-full: venv $(BUILD)/native/uwbcal-station
	UWBCAL_STATION=$(abspath $(BUILD)/native/uwbcal-station) $(PY) tools/newcomer.py

demo: venv $(BUILD)/native/uwbcal-station
	UWBCAL_STATION=$(abspath $(BUILD)/native/uwbcal-station) $(PY) -m uwbcal demo --scenario $(DEMO_SCENARIO)

bench: venv $(BUILD)/native/uwbcal-station usbhosted
	UWBCAL_STATION=$(abspath $(BUILD)/native/uwbcal-station) $(PY) tools/bench/run.py

clean:
	rm -rf $(BUILD)
