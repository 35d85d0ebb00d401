# Two entry points: `make demo` and `make test`. Both create .venv and install the pinned
# dependencies first (torch==2.13.0 CPU comes from the local wheel or PyPI).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Anny's blend-shape cache (about 1.1 GB, built once in about 90 s) and dressed garments
export ANNY_CACHE_DIR ?= $(CURDIR)/.cache/anny
export TRYON_CACHE_DIR ?= $(CURDIR)/.cache/tryon

.PHONY: demo test test-fast bench clean

$(STAMP): pyproject.toml scripts/system-deps.sh
	bash scripts/system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q -e ".[test]"
	-$(BIN)/pip install -q "scikit-sparse==0.4.16" || echo "note: CHOLMOD (scikit-sparse) unavailable; using SciPy SuperLU"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/tryon drape --height-cm 172 --weight-kg 84 --gender male --garment tshirt --size M --fabric gray-interlock --out out/demo
	@echo "demo outputs: out/demo (render_front/back/side.png, fit_map.png, pressure_map.png, garment.obj, body.obj, tryon.glb, report.json)"

# the suite on TEST_WORKERS processes (pytest-xdist; default: one per core, at most 4,
# since each worker holds the body model and the simulator's threads)
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)

test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --durations=30

# the fast tier (under 2 minutes): no drapes, Anny fits, Ray sessions or long runs
test-fast: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_WORKERS) -m "not slow and not anny and not ray"

bench: $(STAMP)
	$(BIN)/tryon bench sim --json out/bench_sim.json

clean:
	rm -rf $(VENV) out build src/*.egg-info
