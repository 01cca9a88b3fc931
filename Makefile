# Two commands on a fresh machine: `make demo` and `make test`. Both install what they need
# into .venv first (system libraries through apt-get when missing).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT := out
DATA := ../shared/data

.PHONY: install demo test docs bench clean system-deps gar-data gar-data-128 gar-gpu landmark-data \
	landmark-annotated landmark-profiled landmark-synthetic landmark-train landmark-gpu landmark-onnx \
	gpu-probe gpu-travel-landmarks gpu-travel-gar gpu-restore

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
	# shot cuts (morphable.shots): PySceneDetect with --no-deps as well, because its declared
	# opencv-python would overwrite the headless cv2 too; what it does import (click,
	# platformdirs, tqdm, numpy) is in the video extra
	$(BIN)/python -m pip install -q --no-deps 'scenedetect>=0.7,<0.8'
	touch $@

demo: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/morphable sample --model sfm --identity-std 1 --expression happiness=0.8 --out $(OUT)/sample.obj
	$(BIN)/morphable info --model sfm --json > $(OUT)/model.json
	$(BIN)/morphable fit $(DATA)/images/image_0010.png --landmarks $(DATA)/images/image_0010.pts \
		--model sfm --out-mesh $(OUT)/fit.obj --report $(OUT)/fit.json --overlay $(OUT)/overlay.png
	@echo "wrote $(OUT)/sample.obj $(OUT)/model.json $(OUT)/fit.obj $(OUT)/fit.json $(OUT)/overlay.png"

# the GAR's real training pack (docs/neural.md, "Real training data"); ~5 min on the 2 cores
gar-data: $(STAMP)
	$(BIN)/python -m neural.gar.build_real --data $(DATA) --out gar_data/real64.npz --workers 2

# the same photos at 128 px for the GPU recipe, normals stored at 64 px so that the pack (56 MiB)
# and the tree stay within the 64 MiB that reach a GPU machine (docs/neural.md, "GPU recipe");
# refits nothing after gar-data (the fits are cached in gar_data/)
# GAR128_MIB=34 for a GPU run that continues the committed GARs (docs/gpu_runs.md)
GAR128_MIB ?= 57
gar-data-128: $(STAMP)
	$(BIN)/python -m neural.gar.build_real --data $(DATA) --out gar_data/real128.npz --resolution 128 \
		--normal-resolution 64 --jpeg-quality 60 --max-mib $(GAR128_MIB) --workers 2

# the landmark network's real packs (docs/landmark_packs.md) into the ignored landmark_data/:
# the annotated photos (~10 min on the 2 cores), then the profiled ones (~30 min); a rerun
# finishes a killed build. The synthetic faces: `python -m neural.faces.build_synthetic`
landmark-data: landmark-synthetic landmark-annotated landmark-profiled

# 10,000 SFM and 6,000 ICT faces at 160 px (SFM: 199 s of rendering on 2 idle cores)
landmark-synthetic: $(STAMP)
	$(BIN)/python -m neural.faces.build_synthetic --out landmark_data/synthetic_sfm160 --n 10000 \
		--resolution 160 --seed 1 --model sfm --workers 2 --data $(DATA)
	$(BIN)/python -m neural.faces.build_synthetic --out landmark_data/synthetic_ict160 --n 6000 \
		--resolution 160 --seed 2 --model ict --workers 2 --data $(DATA)

LANDMARK_PACKS = --synthetic landmark_data/synthetic_sfm160 landmark_data/synthetic_ict160 \
	--annotated landmark_data/annotated --profiled landmark_data/profiled

# the CPU recipe (docs/landmark_net.md); rerun to resume from runs/landmarks/checkpoint.pt
landmark-train: $(STAMP)
	$(BIN)/python -m neural.landmarks.train --out runs/landmarks --recipe cpu $(LANDMARK_PACKS)

# the committed weights exported to ONNX beside them (landmarks.onnx, what detection runs on
# onnxruntime: docs/landmark_net.md, "Without torch"); rerun after changing landmarks.pt
landmark-onnx: $(STAMP)
	$(BIN)/python -m neural.landmarks.export --weights neural/landmarks/weights/landmarks.pt

# the GPU run (docs/gpu_runs.md), on the GPU machine: 8,000 synthetic faces rendered there on
# its 16 cores, the carried compact real packs, LANDMARK_MINUTES of training continuing
# LANDMARK_INIT (the committed network; empty: from scratch, e.g. LANDMARK_ARCH=wide)
LANDMARK_ARCH ?= small
LANDMARK_INIT ?= neural/landmarks/weights/landmarks.pt
LANDMARK_MINUTES ?= 5
landmark-gpu:
	$(GPU_PYTHON) -m neural.gpu_recipe landmarks --generate 8000 --kit gpu_kit/data \
		--annotated landmark_data/annotated_trainval_128.npz --profiled landmark_data/profiled_128.npz \
		--arch $(LANDMARK_ARCH) $(if $(LANDMARK_INIT),--init $(LANDMARK_INIT)) \
		$(if $(GPU_BATCH),--batch-size $(GPU_BATCH)) --minutes $(LANDMARK_MINUTES) --out $(GPU_OUT)

landmark-annotated: $(STAMP)
	$(BIN)/python -m neural.faces.build_annotated --data $(DATA) --out landmark_data/annotated

landmark-profiled: $(STAMP)
	$(BIN)/python -m neural.faces.build_profiled --data $(DATA) --out landmark_data/profiled \
		--per-photo 6 --aflw 300

test: $(STAMP)
	$(BIN)/python -m pytest -q

# the API reference from the docstrings (docs/api): HTML in build/docs/html; a warning (a
# reference to nothing, a section numpydoc cannot parse, a module that does not import) fails it
docs: $(STAMP)
	$(BIN)/python docs/api/build.py build/docs
	@echo "wrote build/docs/html/index.html"

# the GPU recipe (docs/neural.md, "GPU recipe"): the 64-px, 128-px and lambda_n = 0 GARs side by
# side, then two inverters, in about 8 minutes on one GPU; weights, recipe.json and log.txt in
# GPU_OUT. Runs with the GPU machine's own Python (torch with CUDA), not the CPU-only .venv;
# the pack is built here by `make gar-data-128` into the ignored gar_data/ and travels with
# the working tree
GPU_PYTHON ?= python3
GPU_OUT ?= runs/gpu
GAR_MINUTES ?= 1.5
gar-gpu:
	$(GPU_PYTHON) -m neural.gpu_recipe gar --data gar_data/real128.npz --out $(GPU_OUT) \
		--runs runs/gpu-recipe --minutes $(GAR_MINUTES) --inverter-minutes 0.5 --device cuda \
		--continue $(if $(GPU_BATCH),--batch-size $(GPU_BATCH))

# the one-minute throughput probe (docs/gpu_runs.md): images/s of GPU_PROBE's recipes at batch
# 64, 256 and 512 on random data of the real shapes, into GPU_OUT/probe.json
GPU_PROBE ?= landmarks,landmarks-wide
gpu-probe:
	$(GPU_PYTHON) -m evaluation.bench_training_step --recipes $(GPU_PROBE) --device cuda --amp bf16 \
		--channels-last --batch-size 64,256,512 --steps 30 --sync-every 25 --report $(GPU_OUT)/probe.json

# here, before the device call: what travels (neural.gpu_travel), the tracked files the run does
# not read parked out of the tree; gpu-restore after it
gpu-travel-landmarks: $(STAMP)
	$(BIN)/python -m neural.gpu_travel kit --data $(DATA)
	$(BIN)/python -m neural.gpu_travel park landmarks
gpu-travel-gar: $(STAMP)
	$(BIN)/python -m neural.gpu_travel park gar
gpu-restore: $(STAMP)
	$(BIN)/python -m neural.gpu_travel restore

clean:
	rm -rf $(OUT) .pytest_cache
