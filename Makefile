# specsynth: `make demo` and `make test` install everything they need on a fresh Debian machine.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
JOBS   ?= 2
export PYOPENGL_PLATFORM ?= egl

.PHONY: install demo test test-slow test-all bench bench-vga bench-vga-full schema docs lint clean

install: $(STAMP)

PLUGINS := backends/cycles backends/mitsuba backends/photo

$(STAMP): pyproject.toml $(addsuffix /pyproject.toml,$(PLUGINS)) examples/plugin_backend/pyproject.toml scripts/install-system-deps.sh scripts/install-assets.sh
	./scripts/install-system-deps.sh
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (Python 3.11)"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[all]' $(addprefix -e ,$(PLUGINS))
	$(BIN)/pip install -q examples/plugin_backend  # the out-of-tree example; the tests run it
	./scripts/install-assets.sh $(BIN)/python
	touch $(STAMP)

demo: install
	$(BIN)/specsynth build specs/demo.yaml --out out/demo --jobs $(JOBS)
	$(BIN)/specsynth build specs/demo_bl.yaml --out out/demo_bl --jobs $(JOBS)

# The core's tests and each backend's own (backends/<name>/tests).
TESTS := tests $(addsuffix /tests,$(PLUGINS))

# The default suite: everything but the slow PBR renders (< ~20 min on 2 cores).
test: install
	$(BIN)/lint-imports
	$(BIN)/pytest -q -m "not slow" -p no:cacheprovider $(TESTS)

test-slow: install
	$(BIN)/pytest -q -m "slow" -p no:cacheprovider $(TESTS)

test-all: install
	$(BIN)/lint-imports
	$(BIN)/pytest -q -p no:cacheprovider $(TESTS)

bench: install
	$(BIN)/specsynth bench specs/demo.yaml --out bench-out/demo --views 2 --scale 0.25 --ref-factor 4

# The paper-high error at full VGA, both backends, one demo view (docs/performance.md): the first
# run renders the references (two paper-high renders per backend of the image's centre 16 %);
# later runs read them from bench-out/vga and render only the denoised rungs.
bench-vga: install
	$(BIN)/specsynth bench specs/demo.yaml --out bench-out/vga --views 1 --scale 1.0 --ref-factor 2 --ref-crop 0.4 \
		--backend cycles --backend mitsuba --levels high \
		--only high,high+denoise@4,high+denoise@9,high+denoise@16,high+denoise@4x2 \
		--set backend.denoise_quality=high --set backend.denoise_prefilter=none

# The same bench on the whole image: the true VGA numbers, at a first run of about 20 minutes.
bench-vga-full: install
	$(BIN)/specsynth bench specs/demo.yaml --out bench-out/vga_full --views 1 --scale 1.0 --ref-factor 2 \
		--backend cycles --backend mitsuba --levels high \
		--only high,high+denoise@4,high+denoise@9,high+denoise@16,high+denoise@4x2 \
		--set backend.denoise_quality=high --set backend.denoise_prefilter=none

schema: install
	$(BIN)/specsynth schema

# The documentation site from docs/ into site/ (broken links and pages outside the nav fail it).
docs: install
	$(BIN)/python scripts/docs_reference.py
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

clean:
	rm -rf out bench-out site .pytest_cache
