# The two commands of a fresh clone (README, "Two commands"):
#   make demo   set up .venv if missing, install as README's "Install" says (.[dev]), run the demo into
#               demo_out/ (DEMO_OUT=DIR for another folder, DEMO_ARGS=--quick for the short one)
#   make test   set up the same way, then `ruff check .` and README's test command: every test but the
#               whole-command runs of a minute or more (pytest mark long; CI runs it)
#   make test-e2e  the whole-command runs left out of make test: the demo, the zoo recipes, DDP
#               training (pytest mark long; CI runs it after make test)
#   make check  the fast check while working: `ruff check .` and the tests that are neither end to end
#               nor slow (pytest marks e2e, slow; under 2 minutes on 2 cores)
#   make docs   install the docs extra if missing (.[docs]) and build the documentation strict into site/:
#               a broken link, image or anchor fails it (CI runs it)
PYTHON ?= python3
VENV ?= .venv
DEMO_OUT ?= demo_out
DEMO_ARGS ?=
PYTEST_ARGS ?= -n 2 --durations=15
STAMP := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: demo test test-e2e check docs setup zoo

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/python -m c3f_demo --out $(DEMO_OUT) $(DEMO_ARGS)

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS) -m "not slow and not long"

test-e2e: $(STAMP)
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS) -m "long and not slow"

check: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/python -m pytest -n 2 -q -m "not e2e and not slow"

$(DOCS_STAMP): pyproject.toml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(VENV)/bin/mkdocs build --strict --site-dir site

# the zoo's models, each by its recipe (python -m c3f_models zoo train NAME; resumable: rerun to continue)
zoo: $(STAMP)
	$(VENV)/bin/python -m c3f_models zoo train c3f-depth-r18w32
	$(VENV)/bin/python -m c3f_models zoo train c3f-features-r18w32
