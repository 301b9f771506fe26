# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= $(MUJOCO_GL)
# Small dense problems: BLAS threads only fight each other (and pytest -n 2) on two cores.
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1

.PHONY: demo test test-quick lint bench leaderboard real-data lab-decisions sessions clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test,bench,cluster,dev,video]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/sixaxis demo

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -n 2 --durations=15

test-quick: $(STAMP)
	$(BIN)/python -m pytest -n 2 -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python benchmarks/kinematics.py
	$(BIN)/python benchmarks/lab.py
	$(BIN)/python benchmarks/env.py
	$(BIN)/python benchmarks/wrappers.py
	$(BIN)/python benchmarks/mpc.py
	$(BIN)/python benchmarks/mpc_diagnose.py
	$(BIN)/python benchmarks/isolation.py
	$(BIN)/python benchmarks/compensation.py

# The lab on public real data beside the published results and FIGAROH: results/real_data.md;
# each UR10 session left out and updated with k of its poses: results/ur10_sessions.md.
# The Rokae rows need the converted data: SIXAXIS_REAL_DATA=DIR make real-data (docs/lab.md, "Real measurements").
real-data: $(STAMP)
	$(BIN)/python benchmarks/real_data.py
	$(BIN)/python benchmarks/ur10_physics.py
	$(BIN)/python benchmarks/ur10_sessions.py

# How often the lab's decisions are right over 2,100 seeded campaigns (about 20 min of CPU on two
# cores; resumable): results/lab_decisions.md and .json, and the table of README.md and docs/lab.md.
lab-decisions: $(STAMP)
	@git diff --quiet HEAD -- . || { echo "make lab-decisions: commit your changes first (the results must name a clean commit)"; exit 2; }
	$(BIN)/python benchmarks/lab_decisions.py

# A calibration across sessions over 1,000 seeded campaigns (resumable, two workers):
# results/sessions.md and .json (benchmarks/sessions.py; about 1.5 s of CPU a campaign).
sessions: $(STAMP)
	@git diff --quiet HEAD -- . || { echo "make sessions: commit your changes first (the results must name a clean commit)"; exit 2; }
	$(BIN)/python benchmarks/sessions.py

# The published leaderboard, from this checkout's commit (which must have no local changes): the
# full sweep into runs/full-<commit> (resumable: the same command continues it), then the tables,
# plots and JSON in results/ and the README's leaderboard section.
leaderboard: $(STAMP)
	@git diff --quiet HEAD -- . || { echo "make leaderboard: commit your changes first (the records must name a clean commit)"; exit 2; }
	$(BIN)/sixaxis sweep experiments/configs/full.toml --out runs/full-$$(git rev-parse --short=10 HEAD)
	$(BIN)/sixaxis leaderboard runs/full-$$(git rev-parse --short=10 HEAD) --readme README.md

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache build *.egg-info
