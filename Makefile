# Two commands on a fresh machine: `make demo` and `make test`. Both install what they need
# into .venv first (system libraries through apt-get when missing).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT := out
DATA := ../shared/data

.PHONY: install demo test bench clean system-deps gar-data gar-gpu

install: $(STAMP)

# open3d links libusb; pyvista's off-screen screenshots use xvfb when VTK has no OSMesa/EGL
system-deps:
	@if ! ldconfig -p | grep -q libusb-1.0.so.0 || ! command -v xvfb-run >/dev/null; then \
		echo "installing libusb-1.0-0 and xvfb with apt-get"; \
		(apt-get update -qq && apt-get install -y -qq libusb-1.0-0 xvfb >/dev/null) \
		|| echo "warning: apt-get failed: install libusb-1.0-0 and xvfb by hand"; \
	fi

$(STAMP): setup.cfg pyproject.toml | system-deps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip setuptools wheel
	# the local CPU build first, so that the neural extra (torch>=2.2) never pulls CUDA wheels
	$(BIN)/python -m pip install -q torch==2.13.0
	# an egg-info left in the tree by an earlier build shadows the installed entry points
	rm -rf morphable.egg-info
	$(BIN)/python -m pip install -q -e '.[all,dev]'
	# the face mesh: mediapipe 0.10.14 is the last wheel that ships its face models; --no-deps
	# because its declared jax, jaxlib, sounddevice and opencv-contrib-python are unused by the
	# face mesh (~180 MB to download, ~670 MB installed, and opencv-contrib-python would
	# overwrite the headless cv2); what it does import is the facemesh extra (docs/detection.md)
	$(BIN)/python -m pip install -q --no-deps mediapipe==0.10.14
	touch $@

demo: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/morphable sample --model sfm --identity-std 1 --expression happiness=0.8 --out $(OUT)/sample.obj
	$(BIN)/morphable info --model sfm --json > $(OUT)/model.json
	$(BIN)/morphable fit $(DATA)/images/image_0010.png --landmarks $(DATA)/images/image_0010.pts \
		--model sfm --out-mesh $(OUT)/fit.obj --report $(OUT)/fit.json --overlay $(OUT)/overlay.png
	@echo "wrote $(OUT)/sample.obj $(OUT)/model.json $(OUT)/fit.obj $(OUT)/fit.json $(OUT)/overlay.png"

# the GAR's real training pack (docs/neural.md, "Real training data"); ~30 min on one core
gar-data: $(STAMP)
	$(BIN)/python -m neural.build_real --data $(DATA) --out gar_data/real64.npz

test: $(STAMP)
	$(BIN)/python -m pytest -q

# the GAR on the packed real photos, on one GPU (<= 8 min; neural/README.md). Runs with the
# GPU machine's own Python (torch with CUDA), not the CPU-only .venv; the pack is built here
# by `make gar-data` into the ignored gar_data/ and travels with the working tree
GPU_PYTHON ?= python3
gar-gpu:
	$(GPU_PYTHON) -m neural.train --config tiny-gpu --data gar_data/real64.npz --out runs/gar-gpu \
		--device cuda --amp bf16 --channels-last --max-minutes 7

clean:
	rm -rf $(OUT) .pytest_cache
