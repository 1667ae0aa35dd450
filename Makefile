# The README's two commands: `make demo` and `make test`. Both set everything up first.
VENV ?= .venv
LOCK ?= requirements/test.lock
N ?= 10
# mavlink: the MAVLink vehicle simulator; xrce: the PX4 stand-in (swarmd-px4-xrce) with
# swarmd as its XRCE agent; xrce-client: the stand-in through MicroXRCEAgent (needs it on
# PATH), swarmd its second client
VEHICLE ?= mavlink
# ROS2=1: each drone also runs a real rclpy node whose discovery swarmd serves (docs/ros2.md)
ROS2 ?= 0
PYTEST_ARGS ?=

.PHONY: setup test lint typecheck unit demo bench clean lock test-latest

setup:
	@VENV=$(VENV) LOCK=$(LOCK) bash scripts/setup.sh

# requirements/*.lock from pyproject.toml's ranges (UPGRADE=1: newest releases in range)
lock: setup
	@bash scripts/lock.sh

# the suite in .venv-latest against the newest releases; the committed lock is not touched
test-latest:
	@bash scripts/test-latest.sh

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

typecheck: setup
	$(VENV)/bin/mypy --strict

unit: setup
	$(VENV)/bin/pytest $(PYTEST_ARGS)

test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy --strict
	$(VENV)/bin/pytest $(PYTEST_ARGS)

demo: setup
	$(VENV)/bin/python -m swarmd_lab.demo --n $(N) --vehicle $(VEHICLE) $(if $(filter 1,$(ROS2)),--ros2,)

bench: setup
	$(VENV)/bin/python bench/codec.py

clean:
	rm -rf $(VENV) .venv-latest .mypy_cache .pytest_cache .ruff_cache .hypothesis demo-out
