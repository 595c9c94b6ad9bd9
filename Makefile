# Set-up and entry points. Every target builds .venv first if it is missing or stale.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# CPU build of PyTorch; this exact version is served locally on the project's machines.
TORCH := torch==2.13.0
# Debian packages the toolkit needs at run time (installed when missing and we are root).
DEB_PACKAGES :=
SHARED ?= ../shared

.PHONY: demo test bench lint format clean deb

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
	  else echo "missing Debian packages:$$missing (install them as root)"; fi; \
	fi

test: $(STAMP) deb
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q

# The whole pipeline on bundled data; it grows with each stage.
DEMO := demo-out
SAMPLES := $(SHARED)/samples
demo: $(STAMP) deb
	@rm -rf $(DEMO) && mkdir -p $(DEMO)
	@if [ ! -d $(SAMPLES) ]; then echo "$(SAMPLES) not found: skipping the real samples"; exit 0; fi; \
	set -e; echo "== importing the real Live Link Face CSVs"; \
	$(BIN)/s2a-capture import $(SAMPLES)/livelinkface -o $(DEMO)/takes; \
	echo "== importing the NeuroSync test take with its audio"; \
	$(BIN)/s2a-capture import $(SAMPLES)/paired/neurosync-trainer-lite-testset/testset.csv \
	  --audio $(SAMPLES)/paired/neurosync-trainer-lite-testset/audio.wav --id neurosync_testset -o $(DEMO)/takes; \
	echo "== importing the FACEGOOD paired takes (rig weights at 30 fps)"; \
	fg=$(SAMPLES)/paired/facegood-audio2face; \
	for npy in $$fg/bs_value/*.npy; do t=$$(basename $$npy .npy); t=$${t#bs_value_}; \
	  $(BIN)/s2a-capture import --matrix $$npy --audio $$fg/wav/$$t.wav --names $$fg/bs_names.txt \
	    --fps 30 --id facegood_$$t -o $(DEMO)/takes; done; \
	echo "== summaries"; $(BIN)/s2a-capture info $(DEMO)/takes; \
	echo "takes written to $(DEMO)/takes"

bench: $(STAMP) deb
	$(BIN)/python -m benchmarks

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf $(VENV) demo-out .pytest_cache
