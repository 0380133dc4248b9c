# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
DOCS_STAMP := $(VENV)/.docs-stamp
DEMO   := runs/demo

.PHONY: demo test test-slow test-busy test-alone docs bench clean builtin-profile rebuild-profiles lock

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml constraints.txt | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test]"
	$(BIN)/python -m detcal.warm  # the numba kernels compiled into their cache now, not in the first run
	touch $(STAMP)

# The main job on the embedded default: calibrate the default simulated park log, writing the profile
# demo-park-laser@1.0.0 into the user profile folder and the report into runs/demo. (Under its default name,
# sim-park-laser, the same calibration reproduces the bundled profile and writes no copy of it.)
demo: $(STAMP)
	$(BIN)/detcal calibrate --name demo-park-laser --out $(DEMO) --force

# The suite without the end-to-end checks marked slow (docs/development.md says which and why); CI runs those next.
test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q -m "not slow"

test-slow: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q -m slow

$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test,docs]"
	touch $(DOCS_STAMP)

# The documentation site (mkdocs-material): the CLI and profile-schema references are generated while it builds
# (docs/hooks.py); a broken link or a missing page fails the build. Output: site/.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# `make test`'s set beside two CPU-burning processes, three times in a row (CI on a shared machine): prints wall and CPU time.
test-busy: $(STAMP)
	$(BIN)/python -m tests.beside_busy --busy 2 --repeat 3 -- -n 2 -q -m "not slow"

# Every fast test file alone, one process each (a test that passes only after another file ran first fails here);
# about 10 minutes of CPU; prints one line per file and exits 1 if any file fails.
test-alone: $(STAMP)
	@status=0; for f in $$(find tests -name 'test_*.py' | sort); do \
	  r=$$($(BIN)/python -m pytest -q -m "not slow" -p no:cacheprovider $$f 2>&1 | tail -n 1); \
	  echo "$$f: $$r"; case "$$r" in *failed*|*error*) status=1;; esac; done; exit $$status

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

# Rebuild every bundled and benchmark profile from its recorded provenance (command, inputs, creation time, source
# commit) and compare it with the file byte for byte (detcal profile rebuild; docs/reference/profile.md). FROM: the
# working folder the recorded commands ran in (the benchmark profiles read ../shared/data/victoria_park from it).
# A hand-written profile (provenance.command 'written by hand ...': the nominal Victoria Park one) has no command
# to run again; it is named and passed over.
FROM ?= .
rebuild-profiles: $(STAMP)
	@status=0; for f in profiles/builtin/*.yaml benchmarks/profiles/*.yaml; do \
	  if grep -q "^  command: 'written by hand" $$f; then echo "$$f: written by hand, nothing to rebuild"; continue; fi; \
	  nice -n 15 $(BIN)/detcal profile rebuild $$f --from $(FROM) || status=1; done; exit $$status

# Refresh constraints.txt to the newest releases the ranges in pyproject.toml allow (then: make builtin-profile, make test).
lock:
	rm -rf .lock-venv && $(PYTHON) -m venv .lock-venv
	.lock-venv/bin/python -m pip install --quiet --upgrade pip
	.lock-venv/bin/python -m pip install --quiet -e ".[test,docs]"
	{ head -n 2 constraints.txt; .lock-venv/bin/python -m pip freeze --exclude-editable | grep -v '^detcal'; } > constraints.tmp && mv constraints.tmp constraints.txt
	rm -rf .lock-venv

clean:
	rm -rf $(VENV) runs site .pytest_cache
