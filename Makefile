# demtool — chain the stages like ISIS tools.
#
#   make demo            synthetic scene → every route → refined DEM → comparison table
#   make test            test suite (installs the test extras into .venv)
#   make bench           benchmarks (installs the bench extras into .venv); bench/_*.py
#                        are modules the benchmarks share, not benchmarks
#
# Variables: WORK (work folder), CONFIG (TOML preset), SYNTH_ARGS (extra synth options),
# TARGET / PARTNER (view names of the target image and its stereo partner).

.DELETE_ON_ERROR:
SHELL := /bin/bash

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMTOOL := $(BIN)/demtool
WORK ?= work/demo
CONFIG ?= configs/navcam.toml
SYNTH_ARGS ?=
TARGET ?= view_00
PARTNER ?= view_01

DT := $(DEMTOOL) $(if $(CONFIG),--config $(CONFIG))
SCENE := $(WORK)/scene
STEREO := $(WORK)/stereo
TRUTH := $(SCENE)/truth_dem_target.tif

# Every DEM the demo makes, compared with the truth at the end.
PRODUCTS := dem_bam dem_siam dem_siam_projective dem_match dem_refined

.PHONY: all demo demo-reports test bench install install-test install-bench clean lint

all: demo

# ---------------------------------------------------------------------- environment
$(VENV)/.installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	$(BIN)/python -m compileall -q -j0 demtool  # editable: pip writes no .pyc
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

$(VENV)/.installed-bench: $(VENV)/.installed
	$(BIN)/python -m pip install -q -e '.[bench]'
	touch $@

# compile every numba kernel once into the cache (demtool warm; NUMBA_CACHE_DIR if set)
install: $(VENV)/.installed
	$(DEMTOOL) warm
install-test: $(VENV)/.installed-test
install-bench: $(VENV)/.installed-bench

# the tests on TEST_JOBS processes (pytest-xdist), a test module's tests in one of them (its
# module-scoped scenes are made once); TEST_JOBS=0 for one process
TEST_JOBS ?= 2
test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) --dist loadfile

lint: $(VENV)/.installed-test
	$(BIN)/ruff check demtool tests bench

bench: $(VENV)/.installed-bench
	@set -e; for script in $(filter-out bench/_%,$(wildcard bench/*.py)); do \
	  echo "=== $$script"; $(BIN)/python $$script; \
	done

# ---------------------------------------------------------------------- the chain
$(SCENE)/scene.json: | $(VENV)/.installed
	$(DT) synth --out $(SCENE) $(SYNTH_ARGS)

# BAM route: select → bundle → dem from points
$(WORK)/selection.json: $(SCENE)/scene.json
	$(DT) select $(SCENE)/view_*.tif --target $(SCENE)/$(TARGET).tif \
	  --cameras $(SCENE)/cameras.npz --scene $(SCENE)/scene.json --out $@

# NavCam is a calibrated camera: its intrinsics are given (--cameras: K of each view), since
# a narrow-field block cannot determine the focal length (bundle would keep its prior).
$(WORK)/bundle.npz: $(WORK)/selection.json
	$(DT) bundle $< --cameras $(SCENE)/cameras.npz --align-cameras $(SCENE)/cameras.npz \
	  --out $@

$(WORK)/dem_bam.tif: $(WORK)/bundle.npz
	$(DT) dem --points $< --scene $(SCENE)/scene.json --out $@

# BAM densified (issue 27): the tie points plus the SIAM pair's disparities, triangulated
# with the bundle's own cameras (no sensor model), merged cell by cell
PRODUCTS += dem_bam_dense
$(WORK)/dem_bam_dense.tif: $(WORK)/bundle.npz $(STEREO)/disparity_sgm.tif $(STEREO)/rectify.npz
	$(DT) dem --points $< --dense $(STEREO)/disparity_sgm.tif $(STEREO)/rectify.npz \
	  --scene $(SCENE)/scene.json --out $@

# SIAM route: rectify → sgm → dem (calibrated, and the study's projective fit to BAM)
$(STEREO)/rectify.npz: $(SCENE)/scene.json
	$(DT) rectify $(SCENE)/$(TARGET).tif $(SCENE)/$(PARTNER).tif --out $(STEREO)

$(STEREO)/disparity_sgm.tif: $(STEREO)/rectify.npz
	$(DT) sgm $(STEREO)/left_rect.tif $(STEREO)/right_rect.tif --rectify $< --out $@

$(WORK)/dem_siam.tif: $(STEREO)/disparity_sgm.tif $(STEREO)/rectify.npz
	$(DT) dem --disparity $< --rectify $(STEREO)/rectify.npz \
	  --cameras $(SCENE)/cameras.npz --scene $(SCENE)/scene.json --out $@

$(WORK)/dem_siam_projective.tif: $(STEREO)/disparity_sgm.tif $(STEREO)/rectify.npz $(WORK)/dem_bam.tif
	$(DT) dem --disparity $< --rectify $(STEREO)/rectify.npz \
	  --reference $(WORK)/dem_bam.tif --out $@

# Area-based matching route (HiRISE DM / LRO NAC)
$(STEREO)/disparity_match.tif: $(STEREO)/rectify.npz
	$(DT) match $(STEREO)/left_rect.tif $(STEREO)/right_rect.tif --rectify $< --out $@

$(WORK)/dem_match.tif: $(STEREO)/disparity_match.tif $(STEREO)/rectify.npz
	$(DT) dem --disparity $< --rectify $(STEREO)/rectify.npz \
	  --cameras $(SCENE)/cameras.npz --scene $(SCENE)/scene.json --out $@

# Shape-from-shading refinement of the SIAM DEM
$(WORK)/dem_refined.tif: $(WORK)/dem_siam.tif
	$(DT) refine $(SCENE)/$(TARGET).tif $< --out $@

# Calibrated frame stereo on the body's map (issue 11): synth --sensor frame (CSM frame
# cameras on the Moon, ISD JSON beside each view) → rectify with the sensor models → sgm →
# dem triangulated through the models → compare with truth_dem_map.tif
FRAME_SCENE := $(WORK)/scene_frame
FRAME_STEREO := $(WORK)/stereo_frame
PRODUCTS += dem_frame

$(FRAME_SCENE)/scene.json: | $(VENV)/.installed
	$(DT) synth --sensor frame --out $(FRAME_SCENE) $(SYNTH_ARGS)

$(FRAME_STEREO)/rectify.npz: $(FRAME_SCENE)/scene.json
	$(DT) rectify $(FRAME_SCENE)/$(TARGET).tif $(FRAME_SCENE)/$(PARTNER).tif \
	  --sensor-left $(FRAME_SCENE)/$(TARGET).json \
	  --sensor-right $(FRAME_SCENE)/$(PARTNER).json --out $(FRAME_STEREO)

$(FRAME_STEREO)/disparity_sgm.tif: $(FRAME_STEREO)/rectify.npz
	$(DT) sgm $(FRAME_STEREO)/left_rect.tif $(FRAME_STEREO)/right_rect.tif --rectify $< --out $@

$(WORK)/dem_frame.tif: $(FRAME_STEREO)/disparity_sgm.tif $(FRAME_STEREO)/rectify.npz
	$(DT) dem --disparity $< --rectify $(FRAME_STEREO)/rectify.npz \
	  --error-out $(WORK)/dem_frame_error.tif --out $@

$(WORK)/reports/dem_frame/report.json: $(WORK)/dem_frame.tif
	$(DT) compare $< $(FRAME_SCENE)/truth_dem_map.tif --out $(WORK)/reports/dem_frame \
	  --label dem_frame

# Map-projected stereo of a line-scan pair (issue 12): synth --sensor linescan (two
# LineScanSensor views rolled ±12.5°, ISDs beside the images) → mapproject both onto the
# smooth prior (the sphere at the scene's mean height, --height 0; the right view on the
# left's grid) → sgm along map x (range from the orthos' matches) → dem triangulated
# back through the line-scan models → compare with truth_dem_map.tif; then refine on the
# map with the raw left image (map-projected onto dem_linescan inside refine).  The
# refine keeps its own spike test (--spike-threshold 4) instead of the NavCam preset's
# median everywhere: the map-projected stereo DEM has no spikes to remove, and a 15-px
# median of every cell costs it the detail SfS then has to recover (measured on the demo
# scene: RMSE 0.64x -> 0.48x of dem_linescan's).  Slope error of dem_linescan_refined:
# 0.487x of dem_linescan's on the demo scene, 0.33-0.43x on seeds 1-7 (the truth
# resampled bicubically onto the DEMs' grid; bench/linescan_route.py prints the table).
LINESCAN_SCENE := $(WORK)/scene_linescan
LINESCAN_STEREO := $(WORK)/stereo_linescan
PRODUCTS += dem_linescan dem_linescan_match dem_linescan_refined

$(LINESCAN_SCENE)/scene.json: | $(VENV)/.installed
	$(DT) synth --sensor linescan --out $(LINESCAN_SCENE) $(SYNTH_ARGS)

$(LINESCAN_STEREO)/left_ortho.tif: $(LINESCAN_SCENE)/scene.json
	$(DT) mapproject $(LINESCAN_SCENE)/$(TARGET).tif --sensor $(LINESCAN_SCENE)/$(TARGET).json \
	  --height 0 --out $@

$(LINESCAN_STEREO)/right_ortho.tif: $(LINESCAN_STEREO)/left_ortho.tif
	$(DT) mapproject $(LINESCAN_SCENE)/$(PARTNER).tif \
	  --sensor $(LINESCAN_SCENE)/$(PARTNER).json --height 0 --grid-like $< --out $@

$(LINESCAN_STEREO)/disparity_sgm.tif: $(LINESCAN_STEREO)/left_ortho.tif \
	  $(LINESCAN_STEREO)/right_ortho.tif
	$(DT) sgm $^ --out $@

$(WORK)/dem_linescan.tif: $(LINESCAN_STEREO)/disparity_sgm.tif \
	  $(LINESCAN_STEREO)/left_ortho.tif $(LINESCAN_STEREO)/right_ortho.tif
	$(DT) dem --disparity $< \
	  --mapprojected $(LINESCAN_STEREO)/left_ortho.tif $(LINESCAN_STEREO)/right_ortho.tif \
	  --error-out $(WORK)/dem_linescan_error.tif --out $@

# The area-based matcher on the same orthoimages (seeds and range from their matches);
# its template's half-width at the footprint's edge stays unmatched (about 7 % of the
# demo grid; RMSE 0.44 GSD), about 20 s on the demo scene.
$(LINESCAN_STEREO)/disparity_match.tif: $(LINESCAN_STEREO)/left_ortho.tif \
	  $(LINESCAN_STEREO)/right_ortho.tif
	$(DT) match $^ --out $@

$(WORK)/dem_linescan_match.tif: $(LINESCAN_STEREO)/disparity_match.tif \
	  $(LINESCAN_STEREO)/left_ortho.tif $(LINESCAN_STEREO)/right_ortho.tif
	$(DT) dem --disparity $< \
	  --mapprojected $(LINESCAN_STEREO)/left_ortho.tif $(LINESCAN_STEREO)/right_ortho.tif \
	  --out $@

$(WORK)/reports/dem_linescan_match/report.json: $(WORK)/dem_linescan_match.tif
	$(DT) compare $< $(LINESCAN_SCENE)/truth_dem_map.tif \
	  --out $(WORK)/reports/dem_linescan_match --label dem_linescan_match

$(WORK)/dem_linescan_refined.tif: $(WORK)/dem_linescan.tif
	$(DT) refine $(LINESCAN_SCENE)/$(TARGET).tif $< \
	  --sensor $(LINESCAN_SCENE)/$(TARGET).json --spike-threshold 4 --out $@

$(WORK)/reports/dem_linescan/report.json: $(WORK)/dem_linescan.tif
	$(DT) compare $< $(LINESCAN_SCENE)/truth_dem_map.tif --out $(WORK)/reports/dem_linescan \
	  --label dem_linescan

$(WORK)/reports/dem_linescan_refined/report.json: $(WORK)/dem_linescan_refined.tif
	$(DT) compare $< $(LINESCAN_SCENE)/truth_dem_map.tif \
	  --out $(WORK)/reports/dem_linescan_refined --label dem_linescan_refined

# Multi-pair stereo of a block and fusion (issue 29): synth --sensor frame with three views
# (frame cameras on the Moon, ISDs beside the images) → `pairs` chooses the stereo pairs
# worth matching (overlap, convergence and B/H in range, sun) and lists them as
# "LEFT RIGHT" lines → per pair (folder LEFT+RIGHT): rectify with the sensor models →
# sgm → dem with its error raster → `fuse` co-registers the pair DEMs to the first and
# combines them (per-cell Huber M-estimate, weights fading towards each DEM's border) →
# compare with truth_dem_map.tif.  With at least BLOCK_SECOND_PASS_PAIRS pairs, a second
# pass: each pair matched again around the first fused DEM (sgm --prior-dem: the right
# image warped by the disparity it predicts, the residual searched) → dem → fuse.  It
# trades the matching window's smoothing for the fused DEM's own fine-scale error, which
# falls with the number of pairs: on synthetic blocks (bench/fuse_block.py) it lowered
# the fused RMSE on every block of 4 or more pairs and raised it on every 3-pair block
# (docs/stages/fuse.md).  The demo's three views give 3 pairs: one pass.
# The scene is 256 px so the block stays a small part of the demo's time.
BLOCK_SCENE := $(WORK)/scene_block
BLOCK_STEREO := $(WORK)/stereo_block
BLOCK_ARGS ?= --views 3 --size 256 --image-size 256
PRODUCTS += dem_block_fused

block_left = $(word 1,$(subst +, ,$(1)))
block_right = $(word 2,$(subst +, ,$(1)))
BLOCK_SECOND_PASS_PAIRS ?= 4
# the pairs' files are kept: the second pass reads them after the first pass's sub-make
.PRECIOUS: $(BLOCK_STEREO)/%/rectify.npz $(BLOCK_STEREO)/%/disparity_sgm.tif \
  $(BLOCK_STEREO)/%/disparity_prior.tif $(BLOCK_STEREO)/%/dem.tif

block_pairs = $(shell tr ' ' + < $(BLOCK_STEREO)/pairs.txt)
block_dems = $(foreach p,$(block_pairs),$(BLOCK_STEREO)/$(p)/dem.tif)
block_dems_prior = $(foreach p,$(block_pairs),$(BLOCK_STEREO)/$(p)/dem_prior.tif)

$(BLOCK_SCENE)/scene.json: | $(VENV)/.installed
	$(DT) synth --sensor frame $(BLOCK_ARGS) --out $(BLOCK_SCENE) $(SYNTH_ARGS)

$(BLOCK_STEREO)/pairs.txt: $(BLOCK_SCENE)/scene.json
	$(DT) pairs $(BLOCK_SCENE)/view_*.json --out $@

$(BLOCK_STEREO)/%/rectify.npz: $(BLOCK_SCENE)/scene.json
	$(DT) rectify $(BLOCK_SCENE)/$(call block_left,$*).tif \
	  $(BLOCK_SCENE)/$(call block_right,$*).tif \
	  --sensor-left $(BLOCK_SCENE)/$(call block_left,$*).json \
	  --sensor-right $(BLOCK_SCENE)/$(call block_right,$*).json --out $(@D)

$(BLOCK_STEREO)/%/disparity_sgm.tif: $(BLOCK_STEREO)/%/rectify.npz
	$(DT) sgm $(@D)/left_rect.tif $(@D)/right_rect.tif --rectify $< --out $@

$(BLOCK_STEREO)/%/dem.tif: $(BLOCK_STEREO)/%/disparity_sgm.tif
	$(DT) dem --disparity $< --rectify $(@D)/rectify.npz \
	  --error-out $(@D)/dem_error.tif --out $@

# the pairs are known once pairs.txt is made: a sub-make builds their DEMs (pairs.txt
# itself where the list is empty, as under `make -n`: a sub-make without a goal would
# build `all` again, recursively)
$(BLOCK_STEREO)/%/disparity_prior.tif: $(BLOCK_STEREO)/fused_pass1.tif
	$(DT) sgm $(@D)/left_rect.tif $(@D)/right_rect.tif --rectify $(@D)/rectify.npz \
	  --prior-dem $< --out $@

$(BLOCK_STEREO)/%/dem_prior.tif: $(BLOCK_STEREO)/%/disparity_prior.tif
	$(DT) dem --disparity $< --rectify $(@D)/rectify.npz \
	  --error-out $(@D)/dem_prior_error.tif --out $@

$(BLOCK_STEREO)/fused_pass1.tif: $(BLOCK_STEREO)/pairs.txt
	$(MAKE) --no-print-directory $(or $(block_dems),$<)
	$(DT) fuse $(block_dems) --out $@

$(WORK)/dem_block_fused.tif: $(BLOCK_STEREO)/pairs.txt
	$(MAKE) --no-print-directory $(or $(block_dems),$<)
	$(if $(word $(BLOCK_SECOND_PASS_PAIRS),$(block_pairs)),\
	  $(MAKE) --no-print-directory $(BLOCK_STEREO)/fused_pass1.tif $(block_dems_prior) && \
	  $(DT) fuse $(block_dems_prior) --out $@,\
	  $(DT) fuse $(block_dems) --out $@)

$(WORK)/reports/dem_block_fused/report.json: $(WORK)/dem_block_fused.tif
	$(DT) compare $< $(BLOCK_SCENE)/truth_dem_map.tif \
	  --out $(WORK)/reports/dem_block_fused --label dem_block_fused

# Comparison of every product with the synthetic truth
$(WORK)/reports/%/report.json: $(WORK)/%.tif
	$(DT) compare $< $(TRUTH) --out $(WORK)/reports/$* --label $*

# The products are independent chains (one scene each, or one product of a shared one):
# a sub-make builds DEMO_JOBS of them at once (two cores: -j2 halves the wait; the
# numba cache takes concurrent writers, and a kernel two of them need at once is compiled by
# one and loaded by the other: demtool.jitcache's compile lock).  DEMO_JOBS=1 for one at a time.
DEMO_JOBS ?= 2
DEMO_REPORTS := $(foreach p,$(PRODUCTS),$(WORK)/reports/$(p)/report.json)

demo: | $(VENV)/.installed
	$(MAKE) --no-print-directory -j$(DEMO_JOBS) demo-reports
	@$(BIN)/python -m demtool.compare.summary $(DEMO_REPORTS)

demo-reports: $(DEMO_REPORTS)

clean:
	rm -rf $(WORK)
