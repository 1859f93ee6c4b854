# line_odom: one set-up path for everything (scripts/setup.sh). See README.md.
#   make setup   create/refresh .venv (pinned deps, tf2_msgs, engine build); fast when nothing changed
#   make demo    set up, then run the demo
#   make test    set up, then run the test suite
VENV_PYTHON := .venv/bin/python
PYTEST_ARGS ?=

.PHONY: setup demo test clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV_PYTHON) -m line_odom demo

# one pytest-xdist worker per core, a test file's tests on one worker (its module fixtures are built once)
test: setup
	$(VENV_PYTHON) -m pytest -q --durations=10 -n auto --dist loadfile test $(PYTEST_ARGS)

# removes what setup and builds created inside the checkout (not ../shared)
clean:
	rm -rf .venv build install log .pytest_cache .hypothesis line_odom_core/_core.*.so line_odom_core/_testing.*.so *.egg-info
