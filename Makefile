# Set-up and entry points. Every target builds .venv first if it is missing or stale.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# CPU build of PyTorch; this exact version is served locally on the project's machines.
TORCH := torch==2.13.0
# Debian packages the toolkit needs at run time (installed when missing and we are root).
DEB_PACKAGES := libportaudio2 libegl1 libgl1-mesa-dri chromium
SHARED ?= ../shared

.PHONY: demo test bench results lint format clean deb demo-import demo-simulate demo-live demo-align demo-dataset demo-train demo-view

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $(TORCH)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

deb:
	@missing=""; for p in $(DEB_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  else echo "missing Debian packages:$$missing (install them as root: sudo apt-get install$$missing)"; fi; \
	fi

test: $(STAMP) deb
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	@# pytest exits 5 when it collected no tests: that is a failure here, never a pass.
	@# two workers (the machine's two cores), a test file each at a time: its module fixtures are made once
	$(BIN)/python -m pytest -q -n 2 --dist loadfile; rc=$$?; [ $$rc -ne 5 ] || echo "pytest collected no tests" >&2; exit $$rc

# The whole pipeline on bundled data; it grows with each stage. Each step is a target of its own.
DEMO := demo-out
SAMPLES := $(SHARED)/samples
NS := $(SAMPLES)/paired/neurosync-trainer-lite-testset
FG := $(SAMPLES)/paired/facegood-audio2face
HAVE_SAMPLES = test -d $(SAMPLES) || { echo "$(SAMPLES) not found: skipping the real samples"; exit 0; }

demo: $(STAMP) deb
	@rm -rf $(DEMO) && mkdir -p $(DEMO)
	@$(MAKE) --no-print-directory demo-import demo-simulate demo-live demo-align demo-dataset demo-train demo-view
	@echo "== done: everything is under $(DEMO)/"
	@ls $(DEMO)

demo-import:
	@echo "== 1. importing the real Live Link Face CSVs"
	@$(HAVE_SAMPLES); $(BIN)/s2a-capture import $(SAMPLES)/livelinkface -o $(DEMO)/takes
	@echo "== 2. importing the NeuroSync take with its 44.1 kHz audio"
	@$(HAVE_SAMPLES); $(BIN)/s2a-capture import $(NS)/testset.csv --audio $(NS)/audio.wav --audio-pairing frame-index \
	  --id neurosync_testset -o $(DEMO)/takes
	@echo "== 3. importing the seven FACEGOOD paired takes (116 rig controls at 30 fps)"
	@$(HAVE_SAMPLES); for npy in $(FG)/bs_value/*.npy; do t=$$(basename $$npy .npy); t=$${t#bs_value_}; \
	  $(BIN)/s2a-capture import --matrix $$npy --audio $(FG)/wav/$$t.wav --names $(FG)/bs_names.txt \
	    --fps 30 --id facegood_$$t -o $(DEMO)/takes || exit 1; done

demo-simulate:
	@echo "== 4. simulating a recording session: 3 speakers, 6 takes of 20 s, take folders with .mov"
	@$(BIN)/s2a-capture simulate -o $(DEMO)/simulated --speakers 3 --takes 6 --seconds 20 --seed 1 --mov
	@$(BIN)/s2a-capture import $(DEMO)/simulated -o $(DEMO)/takes

demo-live:
	@echo "== 5. live capture: a simulated iPhone (5% loss, 5% reordering, 1% duplicates, 20 ms jitter)"
	@echo "      streams a simulated take over UDP on loopback into s2a-capture listen, audio on the same clock"
	@take=$$(ls -d $(DEMO)/takes/*SimSpk01_1 | head -1); \
	$(BIN)/s2a-capture listen -o $(DEMO)/live --port 41111 --duration 120 --audio-file $(DEMO)/replay.wav \
	  --audio-start first-packet --json > $(DEMO)/live.jsonl & pid=$$!; sleep 2; \
	$(BIN)/s2a-capture replay $$take --to 127.0.0.1:41111 --loss 0.05 --reorder 0.05 --duplicate 0.01 \
	  --jitter-ms 20 --seed 1 --audio-out $(DEMO)/replay.wav --json; \
	sleep 1; kill -INT $$pid; wait $$pid; cat $(DEMO)/live.jsonl

demo-align:
	@echo "== 6. aligning every take with audio: offset, drift, VAD trim, 16 kHz audio, uniform frame grid"
	@$(BIN)/s2a-align $(DEMO)/takes -o $(DEMO)/aligned --jobs 2 --skip-without-audio

demo-dataset:
	@echo "== 7. building and validating a dataset of the simulated takes (split by speaker)"
	@$(BIN)/s2a-dataset build $(DEMO)/aligned/*Sim* -o $(DEMO)/dataset-sim --split-by speaker --jobs 2
	@$(BIN)/s2a-dataset validate $(DEMO)/dataset-sim --deep
	@$(BIN)/s2a-dataset stats $(DEMO)/dataset-sim
	@echo "== 8. building and validating a dataset of the real FACEGOOD takes (rig controls that move)"
	@$(HAVE_SAMPLES); $(BIN)/s2a-dataset build $(DEMO)/aligned/facegood_* -o $(DEMO)/dataset-facegood \
	  --channels varying --test facegood_1114_2_05 facegood_1114_3_16 --jobs 2 && \
	  $(BIN)/s2a-dataset validate $(DEMO)/dataset-facegood --deep

demo-train:
	@echo "== 9. training a small Transformer-S2A on the simulated dataset (1 minute at most), evaluating it"
	@rm -rf $(DEMO)/run-s2a
	@$(BIN)/s2a-train fit --data $(DEMO)/dataset-sim --model s2a -o $(DEMO)/run-s2a --max-steps 300 --max-minutes 1 \
	  --set window=120 --set batch_size=8 --set warmup_steps=20 --set eval_every=50 --set log_every=50 \
	  --set lr=1e-3 --set arch.d_model=128 --set arch.ff_dim=512 --set arch.expert_hidden=32 \
	  --set arch.encoder_layers=2 --set arch.decoder_layers=2
	@$(BIN)/s2a-train eval $(DEMO)/run-s2a --data $(DEMO)/dataset-sim
	@echo "== 10. predicting the real NeuroSync speech to a Live Link Face CSV"
	@$(HAVE_SAMPLES); $(BIN)/s2a-train predict $(DEMO)/run-s2a $(NS)/audio.wav -o $(DEMO)/neurosync-s2a.csv

demo-view:
	@echo "== 11. rendering the NeuroSync take beside the prediction (MP4 with audio), curves (PNG), report (HTML)"
	@$(HAVE_SAMPLES); $(BIN)/s2a-view render $(DEMO)/takes/neurosync_testset -o $(DEMO)/neurosync.mp4 \
	  --compare $(DEMO)/neurosync-s2a.csv --labels recording,prediction --size 320 && \
	  $(BIN)/s2a-view plot $(DEMO)/takes/neurosync_testset $(DEMO)/neurosync-s2a.csv --labels recording,prediction \
	    --channels jawOpen,mouthClose,mouthFunnel -o $(DEMO)/neurosync-curves.png
	@$(BIN)/s2a-view report $(DEMO)/dataset-sim -o $(DEMO)/dataset-sim.html

bench: $(STAMP) deb
	$(BIN)/python -m benchmarks

# Reproduces the paper's tables (about 35 minutes on 2 cores): work under results-out/, numbers in
# docs/results.json, the document docs/results.md. RESULTS_ARGS="--quick" for a smoke run.
results: $(STAMP) deb
	$(BIN)/python -m benchmarks.paper --samples $(SAMPLES) $(RESULTS_ARGS)

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

# build/ is where `pip install .` and `pip wheel .` stage the modules: a module since removed stays there and
# would be packed into the next wheel
clean:
	rm -rf $(VENV) demo-out .pytest_cache build
