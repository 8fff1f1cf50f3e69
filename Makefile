# UAV autonomy test range. The two commands a new user needs:
#   make demo   # install what is missing, build, run the main job
#   make test   # install what is missing, build, run every test tier
SHELL := /bin/bash
.DEFAULT_GOAL := help
IN_ENV := scripts/in_env

.PHONY: help setup apt venv build demo test test-unit test-ros test-e2e check lint typecheck format bench train-detector campaign-smoke campaign-loiter docker-build docker-run clean distclean

help: ## list the targets
	@grep -E '^[a-zA-Z0-9_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

setup: ## install Debian packages, the .venv, compile the SITL step (mypyc), build the catkin workspace (idempotent)
	@scripts/setup.sh all

apt: ## only the Debian packages
	@scripts/setup.sh apt

venv: ## only the Python venv
	@scripts/setup.sh venv

build: ## only catkin_make (after setup)
	@scripts/setup.sh build

demo: setup ## run the main job headless and print where its report is
	@$(IN_ENV) scripts/demo

test: setup ## run all test tiers (unit, ros, e2e); non-zero exit on any failure
	@scripts/run_tests.sh all

test-unit: setup ## pure tests, no ROS master
	@scripts/run_tests.sh unit

test-ros: setup ## rostest integration tests with a real roscore
	@scripts/run_tests.sh ros

test-e2e: setup ## SITL + router + ROS stack end-to-end tests
	@scripts/run_tests.sh e2e

check: lint typecheck ## ruff, ruff format and mypy (strict on every pure core); .ci/run runs it before make test

lint: setup
	@$(IN_ENV) ruff check .
	@$(IN_ENV) ruff format --check .

format: setup ## apply ruff formatting and safe fixes
	@$(IN_ENV) ruff format .
	@$(IN_ENV) ruff check --fix .

typecheck: setup
	@$(IN_ENV) scripts/typecheck

bench: setup ## run every benchmark; appends JSON lines to bench/results/latest.jsonl
	@$(IN_ENV) python bench/run.py

train-detector: setup ## opt-in: install torch (CPU) + onnx, generate the training data, train and score the shipped detector (~20 min on 2 cores) -> runs/detector
	@$(IN_ENV) python -m pip --disable-pip-version-check -q install -r requirements-train.txt
	@nice -n 10 $(IN_ENV) uav-dataset generate config/datasets/detector_train.yaml --out datasets/detector_train --workers 2
	@nice -n 10 $(IN_ENV) uav-train-detector datasets/detector_train --out runs/detector --steps 8000 --crop-px 192 --batch-size 16 --seed 0 --threads 2
	@echo "trained: runs/detector/model.onnx (eval.json, curve.png); to ship it: cp runs/detector/model.onnx catkin_ws/src/uav_perception/models/uav_detector.onnx"

campaign-smoke: setup ## the CI-sized campaign (4 short runs) on an embedded Dask cluster -> runs/campaigns/smoke
	@$(IN_ENV) uav-campaign run config/campaigns/smoke.yaml --out runs/campaigns/smoke

campaign-loiter: setup ## the loiter weighting study (32 deterministic runs of 480 s, ~4 h on 2 cores, niced) -> runs/campaigns/loiter_weights
	@nice -n 10 $(IN_ENV) uav-campaign run config/campaigns/loiter_weights.yaml --out runs/campaigns/loiter_weights

docker-build: ## build docker/Dockerfile (needs a Docker engine)
	docker build -f docker/Dockerfile -t uav-test-range .

docker-run: ## run `make demo` in the image
	docker run --rm -it uav-test-range

clean: ## remove the catkin build, the compiled SITL modules and test outputs (keeps .venv and apt)
	rm -rf catkin_ws/build catkin_ws/devel catkin_ws/install artifacts .stamps/catkin_make.log sitl/build

distclean: clean ## also remove the venv and stamps
	rm -rf .venv .stamps
