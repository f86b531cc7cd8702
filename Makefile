# Two entry points for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export TI_SKIP_VERSION_CHECK := ON
export ENABLE_TAICHI_HEADER_PRINT := 0

.PHONY: demo test test-all bench install clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade "pip>=24" setuptools
	$(PY) -m pip install -q -c constraints.txt -e ".[test]"
	# NVIDIA's converter is a test-only peer; its metadata pins an older numpy, so no deps.
	$(PY) -m pip install -q --no-deps usd-convert-gsplat==0.1.15
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/avatarkit demo -o demo_out

test: $(STAMP)
	$(PY) -m pytest -q

test-all: $(STAMP)
	$(PY) -m pytest -q -m ""

bench: $(STAMP)
	for f in benchmarks/*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) demo_out .pytest_cache
