# Two entry points: `make demo` (the main job) and `make test`. Both build .venv themselves.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[test]'
	touch $@

demo: $(STAMP)
	$(BIN)/sm-bt demo

test: $(STAMP)
	$(BIN)/python -m pytest -q
	$(MAKE) --no-print-directory lint

# mypy cannot follow the editable install's mapping of behaviours/ and trees/ onto sm_bt.*, so it
# checks a symlinked view of the installed layout (build/typecheck/sm_bt).
TYPECHECK := build/typecheck

lint: $(STAMP)
	$(BIN)/ruff check sm_bt behaviours trees models tests
	rm -rf $(TYPECHECK) && mkdir -p $(TYPECHECK)/sm_bt
	for f in sm_bt/*; do ln -s "$(CURDIR)/$$f" $(TYPECHECK)/sm_bt/; done
	ln -s "$(CURDIR)/behaviours" $(TYPECHECK)/sm_bt/behaviours
	ln -s "$(CURDIR)/trees" $(TYPECHECK)/sm_bt/trees
	ln -s "$(CURDIR)/models" $(TYPECHECK)/sm_bt/models
	cd $(TYPECHECK) && $(CURDIR)/$(BIN)/mypy --config-file $(CURDIR)/pyproject.toml -p sm_bt

clean:
	rm -rf $(VENV) build *.egg-info
