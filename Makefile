# Two commands on a fresh machine: `make demo` and `make test`.
# Everything bootstraps .venv from pinned requirements first.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

.PHONY: venv test test-fast test-numpy test-core test-bpy demo cv1d fig2 bench lint format clean

venv: $(STAMP)

$(STAMP): requirements.txt requirements-farm.txt pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "Python 3.11 is required (bpy 5.0.1), found " + sys.version' \
		|| (echo "error: Python 3.11 is required; set PYTHON=/path/to/python3.11" >&2; exit 2)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.txt
	# The farm extra (cvsss[farm]: Dask distributed, openjd-cli), pinned, for its tests.
	$(BIN)/python -m pip install --quiet -r requirements-farm.txt
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	@touch $(STAMP)

# Every test (renders through bpy included), then the core again as where numba has no
# wheel (Windows on ARM: NumPy only).
test: $(STAMP)
	$(BIN)/python -m pytest -q
	$(MAKE) --no-print-directory test-numpy

# The inner loop: no renders, no slow statistical tests (a few minutes on 2 cores).
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not bpy and not slow" tests/core tests/sss_addon

# The core with numba and llvmlite unimportable: everything runs on the NumPy backend.
test-numpy: $(STAMP)
	$(BIN)/python -m pytest -q --numpy-only -m "not slow" tests/core

test-core: $(STAMP)
	$(BIN)/python -m pytest -q -m "not bpy" tests/core

test-bpy: $(STAMP)
	$(BIN)/python -m pytest -q -m bpy

# The main job (46-48 min on 2 quiet cores from a clean clone, ground truth included; 1 h 45 min on a slow day): builds the demo_blend scenes, renders their passes with
# Cycles, post-processes every method and writes $(OUT)/demo/report.md. Scale with
# RES=640x360 FRAMES=240 SCENES=flash,boids REF_EVERY=1 GT_EVERY=40 (SCENES empty: all three;
# GT_EVERY=0: no Cycles ground truth; COMPARE_FRAMES=0: no "what you had / what you get" table;
# COMPARE_GT_SPP: that table's ground-truth samples per pixel);
# SOURCE=synthetic generates flash and regular passes analytically, without Blender.
RES       ?= 320x180
FRAMES    ?= 120
SCENES    ?=
REF_EVERY ?= 5
GT_EVERY  ?= 20
COMPARE_FRAMES ?= 2
COMPARE_GT_SPP ?= 4096
SOURCE    ?= blender

demo: $(STAMP)
	$(BIN)/cvsss demo --out $(OUT)/demo --source $(SOURCE) --res $(RES) --frames $(FRAMES) \
		$(if $(SCENES),--scenes $(SCENES)) --reference-every $(REF_EVERY) \
		--ground-truth-every $(GT_EVERY) --compare-frames $(COMPARE_FRAMES) \
		--compare-ground-truth-spp $(COMPARE_GT_SPP)

cv1d: $(STAMP)
	$(BIN)/cvsss cv1d --out $(OUT)

fig2: $(STAMP)
	$(BIN)/cvsss fig2 --out $(OUT)

# Speed and the speed/accuracy trade (issue #6): out/bench/bench.json + plots, per sampling
# backend (NumPy, numba; issue 15). 10 min on 2 quiet cores: frame times at 720p-1440p
# 2.4 min, the Pareto sweep on both backends 3 min, the tiled post on 1 and 2 Dask workers
# at 1280x720 1 min (section workers, issue 16); the memory section runs last.
# `cvsss bench --write-calibration` also refreshes core/data/quality_calibration.json.
# The bench, then Apply on Render's cost per frame against the plain render (issue 46) at
# 640x360 and 1280x720, each a ratio of interleaved renders in one run.
bench: $(STAMP)
	$(BIN)/cvsss bench --out $(OUT)/bench
	for size in 640x360 1280x720; do \
		$(BIN)/python tools/measure/apply_on_render_cost.py --size $$size --frames 4 \
			--rounds 2 --json $(OUT)/bench/apply_on_render_$$size.json || exit 1; \
	done

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf $(OUT) dist build *.egg-info .pytest_cache .ruff_cache

# -- Blender extension -------------------------------------------------------------------
# `make extension` builds one zip per platform, dist/cvsss-<version>-<platform>.zip, with
# Blender's own extension tool (--split-platforms: each zip carries only its platform's
# wheels), validates each and prints their sizes. The wheels the manifest lists (OpenEXR;
# numba + llvmlite for the compiled backend) are fetched by `make wheels`.
BLENDER_EXT     := $(VENV)/lib/python3.11/site-packages/bpy/5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py
EXT_VERSION      = $(shell sed -n 's/^version *= *"\(.*\)"/\1/p' blender_manifest.toml)
# The manifest is the one list: every "./wheels/….whl" line of it.
WHEELS          := $(shell sed -n 's|^ *"\./\(wheels/[^"]*\.whl\)".*|\1|p' blender_manifest.toml)

.PHONY: wheels extension

wheels: $(WHEELS)

# wheels/<name>-<version>-<python>-<abi>-<platform tags>.whl: pip is given the first platform tag.
wheels/%.whl: | $(STAMP)
	$(BIN)/python -m pip download --quiet --only-binary=:all: --no-deps --python-version 3.11 \
		--platform $(firstword $(subst ., ,$(word 5,$(subst -, ,$*)))) \
		"$(word 1,$(subst -, ,$*))==$(word 2,$(subst -, ,$*))" --dest wheels
	@test -f $@ || (echo "error: pip did not fetch $@ (see wheels/)" >&2; exit 1)

# The zip of the platform `make extension` runs on also carries the numba passes compiled
# for that platform's CPU models (core/backends/shipped.py: x86-64-v3 and generic on
# x86-64; 1-1.5 min of CPU each): installed, the first render loads them instead of
# compiling. Run it on each platform for that platform's zip.
extension: wheels | $(STAMP)
	@mkdir -p dist build
	rm -rf dist/cvsss-$(EXT_VERSION)-*.zip build/shipped_passes
	$(BIN)/python $(BLENDER_EXT) build --split-platforms --source-dir . --output-dir dist
	$(BIN)/python tools/ship_passes.py build . build/shipped_passes
	$(BIN)/python tools/ship_passes.py add build/shipped_passes dist/cvsss-$(EXT_VERSION)-*.zip
	@for z in dist/cvsss-$(EXT_VERSION)-*.zip; do \
		$(BIN)/python $(BLENDER_EXT) validate $$z || exit 1; \
	done
	@ls -l dist/cvsss-$(EXT_VERSION)-*.zip | awk '{printf "%-48s %6.1f MB\n", $$9, $$5 / 1e6}'
