# Set-up is two commands on a fresh machine: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test install clean-venv bench aba-codegen

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip wheel setuptools

# torch first, pinned: a CPU build of 2.13.0 is served locally; any other spec pulls CUDA wheels.
# The C++ extension's source and build script too: an edited _aba.cpp is rebuilt, not left stale.
$(STAMP): $(PY) pyproject.toml setup.py integrators/_aba.cpp integrators/_aba_model.hpp integrators/_aba_cobra.c
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[all]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/cobra demo --force  # refreshes its own plots in out/demo

# Two pytest workers, each test file on one (its module fixtures are built once); each worker's
# batches run on one thread (COBRA_THREADS, tests/conftest.py), and the tests of the threaded
# paths ask for two.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# Every benchmark, one after another (never two at once: they time themselves). Hours in all:
# the MuJoCo fits and the diagnosis accuracy dominate. Each writes its table to benchmarks/results/.
bench: $(STAMP)
	$(PY) benchmarks/sim_speed.py
	$(PY) benchmarks/first_run.py
	$(PY) benchmarks/fault_matrix.py
	$(PY) benchmarks/run_io.py
	$(PY) benchmarks/fit_speed.py
	$(PY) benchmarks/recovery.py
	$(PY) benchmarks/stribeck_fidelity.py
	$(PY) benchmarks/interval_coverage.py
	$(PY) benchmarks/diagnose_accuracy.py
	$(PY) benchmarks/mujoco_robustness.py
	$(PY) benchmarks/mujoco_robustness.py --contact stiff
	$(PY) benchmarks/mujoco_robustness.py --current
	$(PY) benchmarks/mujoco_robustness.py --contact stiff --current
	$(PY) benchmarks/mujoco_robustness.py --contact-law soft_constraint
	$(PY) benchmarks/mujoco_robustness.py --floors
	$(PY) benchmarks/mujoco_robustness.py --floors --contact stiff
	$(PY) benchmarks/mujoco_robustness.py --floors --contact-law soft_constraint
	$(PY) benchmarks/diagnose_matrix.py
	$(PY) benchmarks/diagnose_matrix.py --current
	$(PY) benchmarks/diagnose_matrix.py --engines mujoco --mujoco-contact-law soft_constraint
	$(PY) benchmarks/diagnose_matrix.py --engines mujoco --mujoco-contact-law choose --choose-among compliant,soft_constraint
	$(PY) benchmarks/diagnose_matrix.py --engines mujoco --mujoco-contact-law soft_constraint --mujoco-contact stiff
	$(PY) benchmarks/effect_signal.py
	$(PY) benchmarks/frictionloss_shape.py
	$(PY) benchmarks/channel_weighting.py
	$(PY) benchmarks/contact_time_constant.py
	$(PY) benchmarks/contact_law.py
	$(PY) benchmarks/contact_step.py
	$(PY) benchmarks/gear_play_step.py
	$(PY) benchmarks/mujoco_fit.py --configs twin,elliptic_soft --laws soft_constraint,soft_elliptic --channel-weights residual --name mujoco_fit_residual
	$(PY) benchmarks/mujoco_fit.py --configs stiff --laws soft_constraint,soft_elliptic --channel-weights residual --name mujoco_fit_residual_stiff
	$(PY) benchmarks/headline.py  # the README's headline table from benchmarks/results/

# COBRA's ABA as generated C (integrators/_aba_cobra.c, committed), after a change to the URDF's
# joints or link frames: minutes of g++; the next `make install` rebuilds the extension with it.
aba-codegen: $(STAMP)
	$(PY) tools/generate_aba.py

clean-venv:
	rm -rf $(VENV)
