# Two commands do all the set-up on a fresh machine:
#   make demo   -> creates .venv, installs torch (CPU) + thermonet, runs the main job
#   make test   -> same set-up plus Debian's chromium, then ruff, mypy, the import layers
#                  (lint-imports) and the test suite but its `slow` tests (the 25 slowest
#                  listed at the end); `make test-slow` runs the `slow` ones (CI runs both;
#                  tests/README.md says which tests are slow and what fast twin each has)
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
TORCH  := torch==2.13.0
STAMP  := $(VENV)/.installed

.PHONY: venv demo test test-slow test-cpus test-cpus-all qemu bench clean chromium arm-toolchain

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet $(TORCH)
	$(PIP) install --quiet -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/thermonet compare configs/default.yaml --out runs/demo --overwrite

# the report test renders report.html in a real headless browser (Debian's chromium)
chromium:
	command -v chromium >/dev/null || (apt-get update && apt-get install -y --no-install-recommends chromium)

# the C header is cross-compiled for Cortex-M0+/M4F/M7 and emulated (tests/test_mcu.py):
# Debian's bare-metal Arm toolchain and its C library
arm-toolchain:
	command -v arm-none-eabi-gcc >/dev/null && test -d /usr/lib/arm-none-eabi/newlib || \
	  (apt-get update && apt-get install -y --no-install-recommends gcc-arm-none-eabi \
	   libnewlib-arm-none-eabi)

test: $(STAMP) chromium arm-toolchain
	$(VENV)/bin/ruff check thermonet tests experiments export
	$(VENV)/bin/mypy thermonet
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -q -n 2 --durations=25 -m "not slow" tests

# the longer end-to-end checks (a real local Ray, the README's first steps as written, every
# simulated board calibrated then verified, ...); each has a smaller twin in `make test`
test-slow: $(STAMP) chromium arm-toolchain
	$(PY) -m pytest -q -n 2 --durations=25 -m slow tests

# The numerics subset (pytest -m "numerics and not slow": parity, export, runtime, dynamics,
# decisions; the few end-to-end runs marked slow stay native) as on
# two other CPUs, under Debian's qemu-user: an AMD EPYC (AVX2, FMA; torch dispatches AVX2) and
# a Nehalem (no AVX; torch's default kernels).  qemu-user emulates one process, so pytest runs
# without xdist workers (they would start natively) and the two CPUs run side by side, one
# thread each.  Subprocesses a test starts (a compiled C program, the command line) run
# natively: the emulated part is this pytest process, where torch, numpy and onnxruntime run.
# NPY_DISABLE_CPU_FEATURES: Debian 12's qemu 7.2 crashes inside numpy's AVX2 sort; numpy's own
# dispatch is turned off (torch, onnxruntime and the math libraries still see the CPU).
QEMU     := qemu-x86_64
NUMERICS  = $(PY) -m pytest -q -p no:xdist -p no:cacheprovider -m "numerics and not slow" $(CPUS_FILES)
NPY_OFF  := NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
# OpenBLAS (bundled by numpy and scipy) picks its kernels from cpuid; under qemu-user's Nehalem
# model its detection picks a kernel with AVX instructions and numpy's import dies of SIGILL
# (numpy 2.4.6, scipy-openblas 0.3.x, qemu 7.2).  OPENBLAS_CORETYPE names the kernels a real
# Nehalem gets: the emulated CPU then runs what that CPU would.
OPENBLAS_NEHALEM := OPENBLAS_CORETYPE=Nehalem

qemu:
	command -v $(QEMU) >/dev/null || (apt-get update && apt-get install -y --no-install-recommends qemu-user)

# CI runs the choice test (the decisions of three comparisons, tests/test_cpu_choices.py), the
# RBF tail's oracle and the parity modules that fit its time (qemu's TCG is about 20x slower
# than native here); `make test-cpus-all` runs the whole numerics subset (tests/README.md).
CPUS_FILES ?= tests/test_cpu_choices.py tests/test_rbf_tail.py tests/test_c_header.py \
              tests/test_checkpoint.py tests/test_dynamics.py tests/test_tuning.py \
              tests/test_gru.py tests/test_streaming.py tests/test_sensor_model.py \
              tests/test_autopilot_parity.py tests/test_verify.py tests/test_out_of_core.py \
              tests/test_excursions.py tests/test_guard.py

test-cpus-all:
	$(MAKE) test-cpus CPUS_FILES=tests

test-cpus: $(STAMP) qemu
	env OMP_NUM_THREADS=1 $(NPY_OFF) $(QEMU) -cpu EPYC-Rome $(NUMERICS) > .test-epyc-rome.log 2>&1 & epyc=$$!; \
	env OMP_NUM_THREADS=1 $(OPENBLAS_NEHALEM) $(QEMU) -cpu Nehalem $(NUMERICS) > .test-nehalem.log 2>&1; nehalem=$$?; \
	wait $$epyc; epyc=$$?; \
	echo "== -cpu EPYC-Rome"; tail -n 15 .test-epyc-rome.log; \
	echo "== -cpu Nehalem"; tail -n 15 .test-nehalem.log; \
	test $$epyc -eq 0 && test $$nehalem -eq 0

bench: $(STAMP)
	$(PY) experiments/run_all.py

clean:
	rm -rf $(VENV) runs mlflow.db mlruns .pytest_cache
