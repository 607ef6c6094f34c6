# quad_il entry points. Every target does the (idempotent) set-up and build it needs first.
#   make demo    the main job end to end on the default configuration
#   make test    the whole test suite (lint, gtest, rostest, pytest) with a summary line
#   make build   idempotent set-up (apt, .venv, pip) + catkin build
#   make eval [POLICY=runs/x/policy.ts (default: the shipped models/quad_il_policy/policy.ts)] [SET=dev|dev_dense|dev_wide|test|test_dense | SEEDS=9000-9019 EPISODES=20 DENSITY=]
#             [TIER=bare|safety|shield] [CONTROLLERS=expert,cpp] [EVAL_OUT=results/eval]
#             [POLICY_CONFIG=config/policy.yaml] [FORCE_NEW=1] [BACKEND=engine|ros]
#                closed-loop evaluation of the expert and the policy on held-out worlds (docs/inference.md), in
#                process on the rollout engine (default; docs/engine.md) or through ROS (BACKEND=ros, which
#                also flies the Python node: CONTROLLERS=expert,py,cpp)
#   make shell   a shell with the workspace sourced
#   make bench-<component>   BENCH lines of one component (sim, tracker, planner, collector, train, inference, scale,
#                            engine)
#   make lint / make format
SHELL := /bin/bash
.PHONY: setup build test demo eval shell lint format clean

setup:
	@bash scripts/setup.sh

build:
	@bash scripts/build.sh

test: build
	@bash scripts/run_tests.sh

demo: build
	@bash scripts/demo.sh

# Without SET: SEEDS 9000-9019, EPISODES 20 and the sim config's density (run_eval's defaults).
SET ?=
SEEDS ?=
EPISODES ?=
DENSITY ?=
TIER ?= shield
BACKEND ?= engine
CONTROLLERS ?=
EVAL_OUT ?= results/eval
POLICY_CONFIG ?=
FORCE_NEW ?=
POLICY ?= models/quad_il_policy/policy.ts
eval: build
	@test "$(CONTROLLERS)" = expert || test -f "$(POLICY)" || { echo "make eval: POLICY=$(POLICY): no such file (an exported policy.ts; the shipped one is models/quad_il_policy/policy.ts)" >&2; exit 2; }
	@source scripts/env.sh && python -m quad_il.evaluation.run_eval --policy "$(POLICY)" --tier "$(TIER)" \
	  --backend "$(BACKEND)" $(if $(CONTROLLERS),--controllers "$(CONTROLLERS)",) --out "$(EVAL_OUT)" \
	  $(if $(SET),--set $(SET),) $(if $(SEEDS),--seeds "$(SEEDS)",) \
	  $(if $(EPISODES),--episodes $(EPISODES),) $(if $(DENSITY),--density $(DENSITY),) \
	  $(if $(POLICY_CONFIG),--policy-config "$(POLICY_CONFIG)",) $(if $(FORCE_NEW),--force-new,) \
	  $(if $(WORKERS),--workers $(WORKERS),)

bench-%: build
	@bash scripts/bench.sh $*

shell: build
	@bash --rcfile <(echo 'source ~/.bashrc 2>/dev/null; source scripts/env.sh; PS1="(quad_il) $$PS1"') -i

lint: setup
	@bash scripts/lint.sh check

format: setup
	@bash scripts/lint.sh fix

clean:
	rm -rf build devel install build.log
