# Set-up and main jobs. Each target creates .venv if missing and installs what it needs.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.cvj-installed
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
# Small dense systems: a threaded BLAS costs more than it saves (measured 0.3-0.6 ms per 4x4 solve).
export OPENBLAS_NUM_THREADS ?= 1

DEMO_SCENE    ?= config/scenes/fwd_halfshaft.yaml
DEMO_DURATION ?= 4.0
DEMO_OUT      ?= runs/demo
# composed mode (every node and the recorder in one process on one EventsExecutor: the same
# nodes, topics and bag, the fastest mode that keeps separate nodes); DEMO_MODE= for one
# process per node
DEMO_MODE     ?= --composed

.PHONY: all setup kernel demo test test-fast test-stress bench bench-deps clean

all: test

$(STAMP): setup.py setup.cfg package.xml requirements.txt requirements-ros.txt
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.txt
	@$(PY) -c "import rclpy" 2>/dev/null || { echo "rclpy not importable: installing ROS 2 Jazzy wheels"; \
	  $(PY) -m pip install -q --disable-pip-version-check -r requirements-ros.txt; }
	$(PY) -m pip install -q --disable-pip-version-check --no-deps -e .
	@touch $(STAMP)

setup: $(STAMP)

# Compile every method of the numba kernel once (or load it when the cache is warm), for the
# test suite and the benchmark, which use them all (cold compile time: docs/solvers.md "First run").
kernel: $(STAMP)
	$(PY) -m cvj_ros.physics.kernel.warmup

# The demo compiles only what its run calls (one method's stepper, the engine map and the
# monitor's windows in cvj-sim, the outputs in a second process at the same time) before the
# run starts, with a progress line; a warm demo loads only those (docs/solvers.md "First run").
demo: $(STAMP)
	$(VENV)/bin/cvj-sim run $(DEMO_SCENE) --out $(DEMO_OUT) --duration $(DEMO_DURATION) $(DEMO_MODE) --overwrite

# The suite in TEST_WORKERS pytest-xdist processes (one per core of the 2-core machines it is
# sized for; 1 = one process), a test file per process at a time, so a module's fixtures run once.
TEST_WORKERS ?= 2
test: kernel
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile

test-fast: kernel
	$(PY) -m pytest -m "not e2e and not colcon"

# ROS, e2e and process tests 5 times with both cores busy, each repetition on fresh domains
# (scripts/stress.py); prints "stress: N/5 passed".
test-stress: kernel
	$(PY) scripts/stress.py

# The expert baseline (numbalsoda, requirements-bench.txt) builds from source with a Fortran
# compiler: installed here only (gfortran via apt when missing and root); when it cannot be,
# the bench says in one line that the baseline_expert family is skipped and why.
bench-deps: $(STAMP)
	@$(PY) -c "import numbalsoda" 2>/dev/null || { \
	  command -v gfortran >/dev/null 2>&1 || { test "$$(id -u)" = 0 && command -v apt-get >/dev/null 2>&1 \
	    && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gfortran; } \
	    || echo "make bench: gfortran missing and not installable here (root + apt-get needed)"; \
	  $(PY) -m pip install -q --disable-pip-version-check -r requirements-bench.txt \
	    || echo "make bench: numbalsoda did not build (needs gfortran and cmake)"; }

bench: kernel bench-deps
	$(VENV)/bin/cvj-sim bench --real-lockstep --startup --out bench_out

clean:
	rm -rf build install log runs bench_out *.egg-info
