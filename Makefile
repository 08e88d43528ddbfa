# Two commands do all set-up on a fresh machine (Python 3.11):
#   make demo    install into .venv and run the main job on bundled data -> report/index.html
#                a small fleet study -> report/study/report.html, a timetable (GTFS)
#                study -> report/gtfs_study/report.html, then replays three buses of a
#                made-up fleet into the live twin for 3 minutes (its dashboard)
#   make test    install into .venv and run the fast tests (the ones not marked slow)
#   make test-all   ... and every test, the slow ones too (what CI runs)
#   make typecheck  mypy on effects, model, envs, calibration and agents (as CI)
# Every install goes through constraints.txt, which pins torch to the local CPU build 2.13.0.

PYTHON ?= python3
VENV   := .venv
PIP    := $(VENV)/bin/pip install -c constraints.txt
# the same constraints for pip's isolated build environments (pip reads PIP_CONSTRAINT there too)
export PIP_CONSTRAINT := $(CURDIR)/constraints.txt
STAMP  := $(VENV)/.installed
# OpenBLAS picks its kernels by CPU (or by OPENBLAS_CORETYPE), and two kernels differ in the
# last bits of a sum: enough for a behaviour fingerprint, or a near tie between two effects in
# a test, to come out otherwise. The tests were set on its Skylake-X kernels, which any CPU
# with AVX-512 runs: they are used there whatever the environment asks for.
ifneq ($(shell grep -qw avx512bw /proc/cpuinfo 2>/dev/null && echo yes),)
export OPENBLAS_CORETYPE := SkylakeX
endif

.PHONY: demo test test-all bench lint typecheck clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) -e ".[rl,dev,scale,bench,can,twin]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/ebus demo --out report
	$(VENV)/bin/ebus study configs/studies/example.yaml --out report/study --resume
	$(VENV)/bin/ebus study configs/studies/gtfs_example.yaml --out report/gtfs_study --resume
	$(VENV)/bin/ebus twin demo --minutes 3 --db report/twin/twin.sqlite

test: $(STAMP)
	$(VENV)/bin/python -m pytest -n 2 -m "not slow"

test-all: $(STAMP)
	$(VENV)/bin/python -m pytest -n 2 --dist worksteal --durations=40   # the slowest, to keep the whole suite short

bench: $(STAMP)
	$(VENV)/bin/python -m benchmarks.bench_core

lint: $(STAMP)
	$(VENV)/bin/ruff check ebus_env agents tests benchmarks examples

typecheck: $(STAMP)   # mypy on the packages of pyproject's [tool.mypy] files
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) report .pytest_cache
