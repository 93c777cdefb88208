# Two entry points (see README "Quick start"): `make demo` and `make test`. Each makes the virtual
# environment .venv with the machine's python3 and installs what it needs into it.
#
# Where ROS 2 Jazzy is installed (/opt/ros/jazzy), `make test` also runs the ROS suite (test/ros):
# the package is built with colcon and run with ros2 run / ros2 launch on ROS 2's own Python
# (Debian's /usr/bin/python3, as Ubuntu's ROS uses its python3). The package's pip-only
# dependencies go into .venv-ros, a virtual environment over that Python's packages (the way ROS 2's
# documentation adds pip packages), with numpy held at the version ROS 2 was built against.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
ROS_SETUP ?= /opt/ros/jazzy/setup.bash
ROS_SYSTEM_PYTHON ?= /usr/bin/python3
ROS_VENV := .venv-ros
ROS_PIP_PACKAGES := rosbags cyclonedds xacro yourdfpy
HAVE_ROS := $(wildcard $(ROS_SETUP))

.PHONY: demo test docs bench clean

demo: $(VENV)/.installed
	$(BIN)/neforward demo

ifeq ($(HAVE_ROS),)
test: $(VENV)/.installed-test
	$(BIN)/ruff check .
	@echo "make test: no ROS 2 Jazzy at $(ROS_SETUP), so the ROS suite (test/ros) is skipped; install ROS 2 Jazzy to run it"
	$(BIN)/python -m pytest
else
test: $(VENV)/.installed-test $(ROS_VENV)/.installed
	$(BIN)/ruff check .
	@echo "make test: ROS 2 Jazzy found at $(ROS_SETUP): the ROS suite (test/ros) runs, on $(ROS_VENV)/bin/python"
	NEFORWARD_REQUIRE_ROS=1 NEFORWARD_ROS_PYTHON=$(CURDIR)/$(ROS_VENV)/bin/python $(BIN)/python -m pytest
endif

# The documentation site (docs/, Sphinx with MyST Markdown), warnings as errors, into docs/_build/html.
docs: $(VENV)/.installed-docs
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "make docs: the site is in docs/_build/html/index.html"

bench: $(VENV)/.installed-test $(if $(HAVE_ROS),$(ROS_VENV)/.installed)
	$(BIN)/python bench/bench_recursion.py
	$(BIN)/python bench/bench_dynamics.py
	$(BIN)/python bench/bench_stream.py
	$(BIN)/python bench/bench_estimators.py
	$(BIN)/python bench/bench_estimator_family.py --plot docs/estimators.png
	$(BIN)/python bench/bench_estimator_unseen.py
	$(BIN)/python bench/bench_transients.py
	$(BIN)/python bench/bench_kalman.py
	$(BIN)/python bench/bench_causal_cost.py
	$(BIN)/python bench/bench_realdata.py
	$(BIN)/python bench/bench_panda_sigma.py
	$(BIN)/python bench/bench_write_jitter.py
	$(BIN)/python bench/bench_bag.py
	$(BIN)/python bench/bench_bag.py --long
	$(BIN)/python bench/bench_fit.py
	$(BIN)/python bench/bench_fleet.py
	$(BIN)/python bench/bench_dds.py
	$(BIN)/python bench/bench_contact.py --live
	$(BIN)/python bench/bench_interrupts.py
	$(if $(HAVE_ROS),$(BIN)/python bench/bench_ros.py,@echo "make bench: no ROS 2 Jazzy, so bench/bench_ros.py is not run")

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: $(BIN)/python setup.py setup.cfg package.xml
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: $(BIN)/python setup.py setup.cfg package.xml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@ $(VENV)/.installed

$(VENV)/.installed-docs: $(BIN)/python setup.py setup.cfg package.xml
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $@ $(VENV)/.installed

# --without-pip: Debian's ensurepip is a separate package; the system's pip serves the venv.
$(ROS_VENV)/.installed: Makefile
	rm -rf $(ROS_VENV)
	$(ROS_SYSTEM_PYTHON) -m venv --system-site-packages --without-pip $(ROS_VENV)
	$(ROS_VENV)/bin/python -c 'import numpy; print("numpy==" + numpy.__version__)' > $(ROS_VENV)/constraints.txt
	$(ROS_VENV)/bin/python -m pip install --quiet -c $(ROS_VENV)/constraints.txt $(ROS_PIP_PACKAGES)
	touch $@

clean:
	rm -rf $(VENV) $(ROS_VENV) build *.egg-info .pytest_cache .ruff_cache docs/_build
