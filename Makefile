# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
DEMO   := runs/demo

.PHONY: demo test bench clean builtin-profile

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

# The main job on the embedded default: calibrate the default simulated park log,
# writing the profile (user profile folder) and the report (runs/demo).
demo: $(STAMP)
	$(BIN)/detcal calibrate --out $(DEMO) --force

test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_readers.py
	$(BIN)/python benchmarks/bench_detectors.py
	$(BIN)/python benchmarks/bench_calibration.py
	$(BIN)/python benchmarks/bench_slam.py
	$(BIN)/python benchmarks/bench_planes.py
	$(BIN)/python benchmarks/bench_plane_transition.py
	$(BIN)/python benchmarks/bench_glmb.py

# Regenerate the bundled profile with detcal's own calibration (reproducible bytes).
builtin-profile: $(STAMP)
	SOURCE_DATE_EPOCH=1763683200 $(BIN)/detcal calibrate --out runs/builtin --profiles-dir profiles/builtin --force

clean:
	rm -rf $(VENV) runs .pytest_cache
