# Two entry points: `make demo` and `make test`. Both create .venv when missing and install
# torch (pinned; the CPU wheel is found by pip's local configuration) before the package.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
VENDOR := styleerd/serve/static/vendor

.PHONY: demo test install clean bench

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "torch==2.13.0"
	$(BIN)/python -m pip install --quiet -e ".[train,dev]"
	touch $(STAMP)

# the viewer's three.js (its glTF loader) and three-vrm, and the in-browser step's onnxruntime-web, from npm
# (package-lock.json), vendored next to the pages: no CDN
$(VENDOR)/three.module.js: package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	mkdir -p $(VENDOR)
	cp node_modules/three/build/three.module.js node_modules/three/build/three.core.js \
	   node_modules/three/examples/jsm/controls/OrbitControls.js $(VENDOR)/
	cp node_modules/onnxruntime-web/dist/ort.wasm.min.mjs node_modules/onnxruntime-web/dist/ort-wasm-simd-threaded.mjs \
	   node_modules/onnxruntime-web/dist/ort-wasm-simd-threaded.wasm $(VENDOR)/
	mkdir -p $(VENDOR)/loaders $(VENDOR)/utils
	cp node_modules/three/examples/jsm/loaders/GLTFLoader.js $(VENDOR)/loaders/
	cp node_modules/three/examples/jsm/utils/BufferGeometryUtils.js node_modules/three/examples/jsm/utils/SkeletonUtils.js \
	   $(VENDOR)/utils/
	cp node_modules/@pixiv/three-vrm/lib/three-vrm.module.min.js $(VENDOR)/three-vrm.module.js

install: $(STAMP) $(VENDOR)/three.module.js

# the demo writes BVH files and a self-contained page; the live viewer (styleerd serve) needs the vendored
# three.js, built here too where npm is installed
demo: $(STAMP)
	@if command -v npm >/dev/null 2>&1; then $(MAKE) --no-print-directory $(VENDOR)/three.module.js; \
	else echo "npm not found: 'styleerd serve' needs 'make install' (npm) for its viewer; the demo does not"; fi
	$(BIN)/styleerd demo

# the lint and the documentation site (strict: a broken link or an undocumented public function fails) first
test: install
	$(BIN)/ruff check .
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_data.py
	$(BIN)/python benchmarks/bench_train_step.py
	$(BIN)/python benchmarks/bench_train_parallel.py
	$(BIN)/styleerd bench --json docs/bench.json --plot docs/throughput.png
	$(BIN)/python benchmarks/onnx_profile.py
	$(BIN)/python benchmarks/bench_serve.py

clean:
	rm -rf $(VENV) build site *.egg-info node_modules $(VENDOR)
