# quickhealth: two commands on a fresh machine.
#   make demo   the whole loop on the built-in simulated cell
#   make test   lint and every test (CI runs exactly this)
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
UV     := $(VENV)/bin/uv
STAMP  := $(VENV)/.installed
LOCK   := requirements.lock

.PHONY: demo test check lint format bench clean chromium postgres aravis lock upgrade lockcheck

# The environment is exactly requirements.lock (every version pinned, every file checked by
# sha256): pip bootstraps the locked uv, uv makes .venv equal to the lock (from its cache after
# the first time), then quickhealth goes in editable with the locked setuptools.  docs/install.md
# --compile-bytecode: the .pyc files are made once here; where PYTHONDONTWRITEBYTECODE is set
# (this workplace sets it) every process would otherwise compile scipy, matplotlib and textual
# from source again (about 5 s of CPU per command).
$(STAMP): pyproject.toml $(LOCK)
	$(PYTHON) -m venv $(VENV)
	$(PYTHON) tools/lockfile.py bootstrap uv > $(VENV)/uv-requirement.txt
	$(PY) -m pip install --quiet --require-hashes --no-deps -r $(VENV)/uv-requirement.txt
	$(PYTHON) tools/lockfile.py core > $(VENV)/core.lock
	$(UV) pip sync --quiet --python $(PY) --require-hashes --compile-bytecode $(VENV)/core.lock
	$(UV) pip install --quiet --python $(PY) --no-deps --no-build-isolation -e .
	touch $(STAMP)

# One resolution for every platform, preferring one version per package, from PyPI only.
UV_COMPILE = $(UV) pip compile pyproject.toml --all-extras --universal --fork-strategy fewest \
	--python-version 3.11 --generate-hashes --no-config --default-index https://pypi.org/simple \
	--custom-compile-command 'make lock' --quiet -o $(LOCK)

# After editing dependencies in pyproject.toml: a new lock keeping every pin it can.
lock: $(STAMP)
	$(UV_COMPILE)

# Newest versions pyproject.toml allows, then every test on them (docs/install.md: when).
upgrade: $(STAMP)
	$(UV_COMPILE) --upgrade
	$(MAKE) test

# pip freeze compared with the lock: each difference on one line, exit 1 when there is one.
lockcheck: $(STAMP)
	$(PY) tools/lockfile.py check

demo: $(STAMP)
	$(VENV)/bin/quickhealth demo

# Headless Chromium renders the HTML report in its test. Installed when we are root and it is
# missing; the test skips with a clear message when it still is not there.
chromium:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq >/dev/null 2>&1; DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null 2>&1) \
	  && echo "installed chromium for the report test"; } || echo "chromium not available: the HTML report test will skip"

# The PostgreSQL server (Debian package) runs the shared-index tests with the system's pg_ctl.
# Installed when we are root and it is missing; without it those tests fail in CI (CI=true or
# root) and skip only on a developer's machine.
postgres:
	@ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq >/dev/null 2>&1; DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null 2>&1) \
	  && ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1 && echo "installed postgresql for the archive tests"; } || echo "postgresql not available: the PostgreSQL archive tests will fail in CI, skip elsewhere"

# Aravis (the aravis camera backend, tested on its fake GigE Vision cameras): the Debian
# packages of the library, its tools and its GObject introspection data, and the headers
# PyGObject builds against, installed when we are root and missing; then PyGObject and pycairo
# from the lock (built once by uv with the pinned build tools, then taken from uv's cache).
# Without them the aravis tests fail in CI (CI=true or root) and skip elsewhere.
ARAVIS_DEB := aravis-tools gir1.2-aravis-0.8 libgirepository1.0-dev libcairo2-dev pkg-config
aravis: $(STAMP)
	@dpkg -s $(ARAVIS_DEB) >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq >/dev/null 2>&1; DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(ARAVIS_DEB) >/dev/null 2>&1) \
	  && echo "installed aravis for the camera tests"; } || echo "aravis not available: the aravis camera tests will fail in CI, skip elsewhere"
	@$(PY) -c "import gi" >/dev/null 2>&1 || { pkg-config --exists gobject-introspection-1.0 cairo 2>/dev/null && \
	  $(PYTHON) tools/lockfile.py bootstrap pygobject pycairo > $(VENV)/aravis-requirements.txt && \
	  $(UV) pip install --quiet --python $(PY) --require-hashes --no-deps \
	    --build-constraints tools/aravis-build-constraints.txt -r $(VENV)/aravis-requirements.txt; } \
	  || echo "PyGObject not built (no GObject introspection headers): the aravis camera tests will fail in CI, skip elsewhere"

# Two parts (tests/conftest.py): every test but the real-time ones on two worker processes,
# then the real-time ones (stream timing, freeze and stop latency, kills, signals) alone, as a
# station meets the machine.  Both parts always run; the target fails if either failed.
TESTENV := QUICKHEALTH_REQUIRE_SERVICES=1 OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
PYTEST  := $(VENV)/bin/pytest -q -rs -p no:cacheprovider

test: $(STAMP) chromium postgres aravis
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	@status=0; \
	echo "== tests on two workers (all but the real-time ones)"; \
	$(TESTENV) $(PYTEST) -n 2 -m "not serial" || status=1; \
	echo "== real-time tests, alone"; \
	$(TESTENV) $(PYTEST) -m serial || status=1; \
	exit $$status

check: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(VENV)/bin/pytest -q -m "not slow" -x

lint: $(STAMP)
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

bench: $(STAMP)
	for f in benchmarks/*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) build dist *.egg-info
