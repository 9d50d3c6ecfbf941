# User commands. Each does its own set-up on a fresh Debian 12 machine (missing packages, catkin workspace).
#   make test   build everything and run every test; non-zero exit on any failure
#   make bench  build in Release and run the benchmarks; writes docs/BENCHMARKS.md, docs/img/*.png, out/bench/*.json
#               (BENCH_FLAGS=--quick: a smoke run with fewer repetitions; its report is not for quoting)
#   make demo   gait playback through the node, rviz headless under Xvfb; writes out/demo/stats.csv, out/demo/rviz.png
SHELL := /bin/bash
ROOT := $(CURDIR)
WS := $(ROOT)/.ws
# Debian's ROS Python modules live in the system interpreter, not in the pyenv one on PATH.
export PYENV_VERSION := system
export PATH := /usr/bin:$(PATH)
JOBS ?= 2
CATKIN_MAKE := cd $(WS) && catkin_make -DCMAKE_BUILD_TYPE=Release -j$(JOBS)

.PHONY: test bench demo setup build clean

setup:
	@$(ROOT)/tools/setup.sh

build: setup
	@$(CATKIN_MAKE)

# The tests are built on every core but run one at a time: the rostests measure the node's rates against the wall
# clock, and beside the core gtests (two threads) on a 2-core machine they measured the load instead.
test: build
	@rm -rf $(WS)/build/test_results
	@$(CATKIN_MAKE) tests
	@cd $(WS) && catkin_make -DCMAKE_BUILD_TYPE=Release -j1 run_tests
	@catkin_test_results --verbose $(WS)/build/test_results
	@$(ROOT)/tools/summarize_tests.py $(WS)/build/test_results

bench: build
	@$(CATKIN_MAKE) benchmarks
	@mkdir -p $(ROOT)/out/bench
	@start=$$(date +%s); for bench in $(WS)/devel/lib/muscle_deformation/*_bench; do \
	  echo "== $$(basename $$bench) (make bench running for $$(( $$(date +%s) - start )) s)"; \
	  "$$bench" --out $(ROOT)/out/bench $(BENCH_FLAGS) || exit 1; done; \
	  echo "== all benchmarks done in $$(( $$(date +%s) - start )) s"
	@$(ROOT)/tools/bench_report.py $(ROOT)/out/bench $(ROOT)/docs/BENCHMARKS.md

demo: build
	@mkdir -p $(ROOT)/out/demo
	@source $(WS)/devel/setup.bash && /usr/bin/python3 $(ROOT)/tools/demo_gait.py --out $(ROOT)/out/demo

clean:
	rm -rf $(WS) $(ROOT)/out
