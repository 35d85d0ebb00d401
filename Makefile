# Two entry points: `make demo` and `make test`. Both create .venv and install the pinned
# dependencies first (torch==2.13.0 CPU comes from the local wheel or PyPI).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml scripts/system-deps.sh
	bash scripts/system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q -e ".[test]"
	-$(BIN)/pip install -q "scikit-sparse==0.4.16" || echo "note: CHOLMOD (scikit-sparse) unavailable; using SciPy SuperLU"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/tryon simulate --example sphere-drop --out out/demo
	@echo "demo outputs: out/demo (frames.npz, obj/, summary.json, last_frame.png)"

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/tryon bench sim --json out/bench_sim.json

clean:
	rm -rf $(VENV) out build src/*.egg-info
