# mjendo: `make train POLICY=E` and `make test` work from a fresh clone.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
POLICY  ?= E
ENV     ?=
FIDELITY ?= fast

.PHONY: setup test bench lint models targets train finetune ship eval study video clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first: the CPU build 2.13.0 (an unpinned torch pulls a multi-GB CUDA build)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev,study,warp,mesh]'
	touch $(STAMP)

setup: $(STAMP)

# The default tier and the integration tier (wheel, Ray, MuJoCo Warp); `slow` stays out (pytest -m slow).
# One test worker per core (pytest-xdist); Warp's and Ray's tests each keep to one worker.
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -n auto --dist loadgroup --durations=10

bench: $(STAMP)
	$(BIN)/python -m mjendo.bench

lint: $(STAMP)
	$(BIN)/ruff check mjendo tests

# Regenerate the committed scene files (every task version) from the stomach mesh and the config.
# The target lists every policy trained on change only through `make targets`.
models: $(STAMP)
	$(BIN)/python -m mjendo.scene

# Measure the reachability map and draw the target lists again (about 10 min; retrain afterwards).
targets: $(STAMP)
	$(BIN)/python -m mjendo.targets map

train: $(STAMP)
	$(BIN)/python -m mjendo.train --policy $(POLICY) $(if $(TIMESTEPS),--timesteps $(TIMESTEPS)) \
	  $(if $(SEED),--seed $(SEED)) $(if $(N_ENVS),--n-envs $(N_ENVS)) $(if $(BACKEND),--backend $(BACKEND)) \
	  $(if $(VARIANT),--variant $(VARIANT)) \
	  $(if $(filter command line environment,$(origin FIDELITY)),--fidelity $(FIDELITY))

# Copy a finished run into models/policies/<POLICY>/ (RUN= another run folder name than seed0).
RUN ?= seed0
ship: $(STAMP)
	$(BIN)/python -m mjendo.artifacts ship runs/$(POLICY)/$(RUN) $(POLICY)

# Fine-tune a shipped policy in the full FEM stomach (train/policies.yaml's finetune block).
finetune: $(STAMP)
	$(BIN)/python -m mjendo.train --policy $(POLICY) --init-from models/policies/$(POLICY) \
	  $(if $(TIMESTEPS),--timesteps $(TIMESTEPS)) $(if $(SEED),--seed $(SEED))

clean:
	rm -rf $(VENV) *.egg-info

# The paper's study: every shipped policy and the baseline, next to the paper's tables. Writes to
# runs/eval/<fidelity>/ (untracked); OUT=eval/results regenerates the committed study.
TRIALS ?= 200
eval: $(STAMP)
	$(BIN)/python -m mjendo.evaluation --trials $(TRIALS) --fidelity $(FIDELITY) $(if $(OUT),--out $(OUT))

# The multi-seed study on Ray (local cluster, or RAY_ADDRESS / ADDRESS=host:port): trains what is missing,
# resumes what was interrupted, skips what is finished, then reports across-seed intervals.
POLICIES ?= D,E
SEEDS ?= 0,1,2
study: $(STAMP)
	$(BIN)/python -m mjendo.study --policies $(POLICIES) --seeds $(SEEDS) --trials $(TRIALS) \
	  $(if $(TIMESTEPS),--timesteps $(TIMESTEPS)) $(if $(OUT),--out $(OUT)) $(if $(ADDRESS),--address $(ADDRESS))

# Headless recording of shipped policy E in DE.
video: $(STAMP)
	MUJOCO_GL=egl $(BIN)/python -m mjendo.viewer --headless --record out.mp4
