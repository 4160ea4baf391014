# The two commands of the README: `make demo` and `make test`. Each sets itself up.
# `make setup` installs the exact versions of requirements.lock (the set the suite last passed
# on); `make lock` regenerates the lock from pyproject.toml's ranges (newest versions), and
# `make test-latest` runs the suite on those newest versions without touching the lock.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
LOCK   := requirements.lock
EXTRAS := test
export MUJOCO_GL ?= egl
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
PYTEST := -m pytest -q -ra -n auto --dist loadfile --durations=20

.PHONY: demo test setup lock test-latest test-kernels clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml $(LOCK)
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r $(LOCK)
	$(PY) -m pip install --quiet --no-deps -e .
	touch $@

test: setup
	$(PY) $(PYTEST)

# the golden values under a second OpenBLAS kernel, Haswell (CI; docs/testing.md). Skipped where
# the machine sets OPENBLAS_CORETYPE itself (a CPU that needs its own kernel) or lacks AVX2.
test-kernels: setup
	@if [ -n "$${OPENBLAS_CORETYPE:-}" ]; then echo "test-kernels: OPENBLAS_CORETYPE=$$OPENBLAS_CORETYPE is set by this machine; not overridden"; \
	elif ! grep -qw avx2 /proc/cpuinfo 2>/dev/null; then echo "test-kernels: no AVX2 on this CPU; the Haswell kernel cannot run"; \
	else OPENBLAS_CORETYPE=Haswell $(PY) -m pytest -q -ra -n auto tests/test_golden.py; fi

demo: setup
	$(PY) -m testbed demo --out runs/demo

# newest versions allowed by pyproject.toml -> requirements.lock (run it, then `make test`, and
# commit the lock when the suite passes: docs/testing.md)
lock:
	rm -rf .venv-lock
	$(PYTHON) -m venv .venv-lock
	.venv-lock/bin/python -m pip install --quiet --upgrade pip
	.venv-lock/bin/python -m pip install --quiet -e '.[$(EXTRAS)]'
	.venv-lock/bin/python -m pip freeze --exclude-editable | grep -v '^uav-swarm-testbed' > $(LOCK).new
	mv $(LOCK).new $(LOCK)
	rm -rf .venv-lock

# the suite on the newest versions pyproject.toml allows, in its own environment (CI's
# unpinned job: an upstream release that breaks the testbed is seen before the lock moves)
test-latest:
	rm -rf .venv-latest
	$(PYTHON) -m venv .venv-latest
	.venv-latest/bin/python -m pip install --quiet --upgrade pip
	.venv-latest/bin/python -m pip install --quiet --upgrade -e '.[$(EXTRAS)]'
	.venv-latest/bin/python -m pip freeze --exclude-editable
	.venv-latest/bin/python $(PYTEST)

clean:
	rm -rf $(VENV) .venv-lock .venv-latest runs *.egg-info
