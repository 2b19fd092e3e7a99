# The only set-up a user needs: `make demo` runs the main job, `make test` runs the tests.
# Both create .venv on first use; torch==2.13.0 (CPU build) is installed before the rest so pip
# never pulls a multi-GB CUDA build.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
EXTRAS ?= all,dev

.PHONY: install test test-all demo bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check torch==2.13.0
	$(PY) -m pip install -q --disable-pip-version-check -e ".[$(EXTRAS)]"
	touch $(STAMP)

lint: install
	$(VENV)/bin/ruff check cosmos_lite tests bench

test: lint
	$(VENV)/bin/pytest -q

test-all: lint
	$(VENV)/bin/pytest -q -m ""

demo: install
	$(VENV)/bin/cosmos-lite demo

bench: install
	@for b in bench/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache *.egg-info
