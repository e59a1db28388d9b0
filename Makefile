# kinredund: `make demo` runs the main job, `make test` the tests. Both set up .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEPS_STAMP := $(VENV)/.deps-stamp
OUT ?= out
# The default test run skips the slow thesis reproductions; CI (CI=true) runs everything.
PYTEST_SELECT := $(if $(CI),,-m "not slow")
PYTEST_ARGS ?=

.PHONY: venv install demo test test-all lint bench robots browser docs clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The dependencies alone (pyproject.toml's, with the dev extra and the extras it names), not the package: building
# the package here would build the compiled core once more, in an isolated environment, only for `install` to
# build it again (about 10 minutes on 2 cores).
REQUIREMENTS := import tomllib; p = tomllib.load(open("pyproject.toml", "rb"))["project"]; \
	x = p["optional-dependencies"]; own = lambda r: r.startswith("kinredund["); \
	reqs = lambda rs: [s for r in rs for s in (reqs(sum((x[e] for e in r[10:-1].split(",")), [])) if own(r) else [r])]; \
	print("\n".join(reqs(p["dependencies"] + x["dev"])))

$(DEPS_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -c '$(REQUIREMENTS)' > $(VENV)/requirements.txt
	$(BIN)/python -m pip install --quiet -r $(VENV)/requirements.txt
	touch $(DEPS_STAMP)

# The pytest script (not python -m pytest) keeps the checkout off sys.path: tests import the installed wheel.
# Always reinstall the package itself as a built wheel (not editable), so the tests see what users get.
# The compiled core (CMakeLists.txt, src/core/) builds against the venv's own pin (its build requirements are in
# the dev extra, so no isolated build environment is downloaded again); CMake keeps its objects in build/.
# The built core goes into site-packages only: the tests and the benchmarks (benchmarks/_bench.py) import the
# installed package. A checkout on PYTHONPATH has no core (its runs take the Python stepper; a full benchmark
# run refuses it). The rm clears the copy that older Makefiles put into the checkout, which would shadow a
# newer build under PYTHONPATH=$$PWD (.gitignore keeps such a file out of commits).
install: $(DEPS_STAMP)
	$(BIN)/python -m pip install --quiet --no-deps --force-reinstall --no-build-isolation .
	rm -f kinredund/_core*.so

demo: install
	$(BIN)/kinredund demo --out $(OUT)

# Headless Chromium for the browser tests (tests/test_browser.py, tests/test_viz.py): Debian's package. Not
# part of `make test`, which installs no system packages: without chromium those tests skip with the reason.
browser:
	@command -v chromium >/dev/null 2>&1 || (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || echo "chromium could not be installed: the browser tests will be skipped"

# The tracker's tests once more on the Python stepper alone (the default backend is the compiled core, issue 28:
# both must pass; tests/test_tracking_compiled.py compares them step by step).
PYTHON_BACKEND_TESTS := tests/test_tracking_api.py tests/test_tracking_state.py tests/test_tracking_limits.py \
	tests/test_tracking_limits_property.py tests/test_tracking_axis.py tests/test_tracking_failures.py \
	tests/test_tracking_compiled.py tests/test_resolved_rate.py tests/test_record_checks.py \
	tests/test_tracking_clearance.py tests/test_tracking_scene.py tests/test_tracking_self_clearance.py

test: install
	$(BIN)/pytest $(PYTEST_SELECT) $(PYTEST_ARGS)
	KINREDUND_BACKEND=python $(BIN)/pytest $(PYTEST_SELECT) $(PYTEST_ARGS) $(PYTHON_BACKEND_TESTS)

test-all: install
	$(BIN)/pytest $(PYTEST_ARGS)
	KINREDUND_BACKEND=python $(BIN)/pytest $(PYTEST_ARGS) $(PYTHON_BACKEND_TESTS)

lint: $(DEPS_STAMP)
	$(BIN)/ruff check kinredund tests benchmarks examples

# The API reference (pdoc, from the docstrings) into docs/api/; fails on a docstring reference to a name that
# does not exist (docs/build_api.py)
docs: install
	$(BIN)/python docs/build_api.py --out docs/api

robots: install
	$(BIN)/kinredund generate-robots --out robots

bench: install
	$(BIN)/python -m pip install --quiet ".[bench]"
	for b in benchmarks/[!_]*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info $(OUT) docs/api kinredund/_core*.so
