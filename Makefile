# Stand-alone workflow (no ROS install needed). See README.md.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTEST_ARGS ?=

.PHONY: setup test demo lint freeze clean

setup:
	@scripts/setup.sh

test: setup
	$(PY) test/run_suite.py -m 'not hardware' $(PYTEST_ARGS)

demo: setup
	$(PY) -m tlessbot_ros.tools.cli demo

lint: setup
	$(PY) -m ruff check tlessbot_ros test launch
	$(PY) -m mypy

freeze: setup
	@{ echo '# Exact versions CI was green with (pip freeze of a fresh set-up). Regenerate with: make freeze'; \
	  $(PY) -m pip freeze --exclude-editable | grep -v '^tlessbot'; } > constraints.txt

clean:
	rm -rf $(VENV) build install log *.egg-info eval_out
