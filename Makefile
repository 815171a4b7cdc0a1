# Lightwire: the two commands.
#
#   make run   installs what is missing, builds, serves the default scene
#   make bake  the same, but bakes the default scene once to $(OUT)
#   make test  installs what is missing, runs every test (Rust, the
#              dashboard's JavaScript, and the dashboard in headless Chromium)
#              and validates the deployment files (make deploy-check)
#   make test-levels  the tests of the real third-party levels in $(LEVELS)
#              (default ../shared/levels; never copied into the repository)
#   make soak  builds, then the soak benchmark: a solver, a relay, 500 viewers
#              and 2 drivers for 10 minutes on loopback (SOAK_FLAGS, e.g.
#              SOAK_FLAGS="--duration 60"; report in target/soak/)
#   make benchmarks  every measurement BENCHMARKS.md reports, one after the
#              other on this machine (about 80 minutes, the codec step about
#              45 more; nothing else should run; output in
#              target/bench-report/, LEVELS for section 9)
#
# System packages are installed with apt (idempotently: only what is
# missing, and `apt-get update` only when something is).

SHELL := /bin/bash
CARGO ?= cargo
SCENE ?= scenes/cornell-large.json
OUT ?= out/cornell-large
LISTEN ?= 127.0.0.1:8080

# Debian packages the build and the tests need:
#   mesa-vulkan-drivers  lavapipe, the software Vulkan driver the GPU solver
#                        runs on when there is no GPU
#   libvulkan1           the Vulkan loader
#   vulkan-tools         vulkaninfo, to say which adapter is there
#   pkg-config           for -sys crates
#   chromium             the browser the dashboard's end-to-end test drives
#                        (Playwright never downloads one)
APT_PACKAGES := mesa-vulkan-drivers libvulkan1 vulkan-tools pkg-config chromium
# node and npm run the dashboard's tests. Installed from Debian only when no
# `node`/`npm` is on the PATH (a NodeSource nodejs, which bundles npm, counts).
NODE_APT_PACKAGES := nodejs npm
DASHBOARD := server/dashboard

.PHONY: run bake test test-levels soak benchmarks deps check-toolchain build dashboard-deps gltf-validator-deps deploy-tools deploy-check

deps: check-toolchain
	@missing=""; \
	for p in $(APT_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  if [ "$$(id -u)" -ne 0 ]; then SUDO=sudo; else SUDO=; fi; \
	  $$SUDO apt-get update -q && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q --no-install-recommends $$missing; \
	fi
	@if ! command -v node >/dev/null || ! command -v npm >/dev/null; then \
	  echo "installing $(NODE_APT_PACKAGES)"; \
	  if [ "$$(id -u)" -ne 0 ]; then SUDO=sudo; else SUDO=; fi; \
	  $$SUDO apt-get update -q && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q --no-install-recommends $(NODE_APT_PACKAGES); \
	fi

# The dashboard's npm packages (the pinned zstd decoder the page vendors, and
# playwright-core), exactly as package-lock.json says; again only when the
# lock file changed since the last install.
dashboard-deps: deps
	@cd $(DASHBOARD) && if [ ! node_modules/.package-lock.json -nt package-lock.json ]; then \
	  PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund; \
	fi

# The Khronos glTF validator (npm `gltf-validator`, pinned by its
# package-lock.json) that scene/tests/gltf_import.rs runs on the generated
# meshes; installed like the dashboard's packages.
GLTF_VALIDATOR := scene/tests/gltf-validator
gltf-validator-deps: deps
	@cd $(GLTF_VALIDATOR) && if [ ! node_modules/.package-lock.json -nt package-lock.json ]; then \
	  npm ci --no-audit --no-fund; \
	fi

check-toolchain:
	@command -v $(CARGO) >/dev/null || { echo "error: cargo not found; install the Rust toolchain (https://rustup.rs)"; exit 1; }
	@rustup component list --installed 2>/dev/null | grep -q rustfmt || rustup component add rustfmt clippy 2>/dev/null || true

build: deps
	$(CARGO) build --release --workspace

# Development mode (no tokens): loud on purpose, bound to loopback.
run: build
	@echo "starting lightwire serve on $(SCENE); open http://$(LISTEN)/ (Ctrl-C stops it)"
	./target/release/lightwire serve --scene $(SCENE) --listen $(LISTEN) --dev

bake: build
	./target/release/lightwire bake --scene $(SCENE) --solver progressive --out $(OUT)
	@echo
	@echo "baked $(SCENE): open $(OUT)/lightmap.png (tone-mapped) or $(OUT)/lightmap.exr (linear HDR);"
	@echo "$(OUT)/atlas.json maps surfaces to atlas rectangles, $(OUT)/stats.json has the numbers,"
	@echo "$(OUT)/scene.glb is the scene lit by the lightmap for any glTF viewer."

# docs/benchmarks-history.md, "Soak". The script builds nothing and stops by itself.
SOAK_FLAGS ?=
soak: build
	client/bench/soak.sh $(SOAK_FLAGS)

# BENCHMARKS.md's figures, measured again together; the script builds first.
benchmarks: deps
	LEVELS=$(LEVELS) client/bench/report.sh

# Validators for deploy/, from PyPI into a venv under target/ (reinstalled
# only when the pinned versions change). Both work offline once installed:
# kubernetes-validate bundles the Kubernetes JSON schemas, check-jsonschema
# the Compose Specification's schema.
DEPLOY_TOOLS := target/deploy-tools
DEPLOY_PIP := kubernetes-validate==1.37.0 check-jsonschema==0.39.0
# The oldest Kubernetes the manifests target (the StatefulSet pod-index
# label needs 1.28).
KUBERNETES_VERSION := 1.30.0

deploy-tools:
	@if [ "$$(cat $(DEPLOY_TOOLS)/.installed 2>/dev/null)" != "$(DEPLOY_PIP)" ]; then \
	  echo "installing $(DEPLOY_PIP) into $(DEPLOY_TOOLS)"; \
	  rm -rf $(DEPLOY_TOOLS); \
	  if ! python3 -m venv $(DEPLOY_TOOLS) >/dev/null 2>&1; then \
	    if [ "$$(id -u)" -ne 0 ]; then SUDO=sudo; else SUDO=; fi; \
	    $$SUDO apt-get update -q && \
	    DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q --no-install-recommends python3 python3-venv && \
	    rm -rf $(DEPLOY_TOOLS) && python3 -m venv $(DEPLOY_TOOLS) || exit 1; \
	  fi; \
	  $(DEPLOY_TOOLS)/bin/pip install -q $(DEPLOY_PIP) && echo "$(DEPLOY_PIP)" > $(DEPLOY_TOOLS)/.installed; \
	fi

# The Kubernetes manifests against the Kubernetes JSON schemas (strict: no
# unknown fields), compose.yaml against the Compose Specification, the
# scenes ConfigMap against scenes/, and the broken fixtures in deploy/tests/
# must be refused (so a validator that accepts anything fails this target).
deploy-check: deploy-tools
	$(DEPLOY_TOOLS)/bin/kubernetes-validate --strict --quiet -k $(KUBERNETES_VERSION) deploy/k8s/*.yaml
	$(DEPLOY_TOOLS)/bin/check-jsonschema --builtin-schema vendor.compose-spec deploy/compose.yaml
	@deploy/k8s/gen-scenes.sh target/scenes.yaml.check && diff -u deploy/k8s/scenes.yaml target/scenes.yaml.check \
	  || { echo "deploy/k8s/scenes.yaml is stale: run deploy/k8s/gen-scenes.sh"; exit 1; }
	@if $(DEPLOY_TOOLS)/bin/kubernetes-validate --strict --quiet -k $(KUBERNETES_VERSION) deploy/tests/broken-statefulset.yaml >/dev/null 2>&1; then \
	  echo "kubernetes-validate accepted deploy/tests/broken-statefulset.yaml"; exit 1; fi
	@if $(DEPLOY_TOOLS)/bin/check-jsonschema --builtin-schema vendor.compose-spec deploy/tests/broken-compose.yaml >/dev/null 2>&1; then \
	  echo "check-jsonschema accepted deploy/tests/broken-compose.yaml"; exit 1; fi
	@echo "deploy/: manifests and compose file valid; broken fixtures refused"

# The dashboard's browser test (server/tests/dashboard.rs) runs inside
# `cargo test`; its screenshots land in target/dashboard-artifacts/.
test: deps dashboard-deps gltf-validator-deps deploy-check
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	cd $(DASHBOARD) && node --test test/
	$(CARGO) test --workspace

# The real levels (../shared/levels/README.md) stay outside the repository;
# their tests are a feature of lightwire-server that `make test` leaves off.
LEVELS ?= ../shared/levels
test-levels: deps dashboard-deps
	@test -f "$(LEVELS)/README.md" || { echo "error: no levels at $(LEVELS) (make test-levels LEVELS=/path/to/levels)"; exit 1; }
	$(CARGO) clippy -p lightwire-server --features levels --tests -- -D warnings
	LEVELS="$(abspath $(LEVELS))" $(CARGO) test -p lightwire-server --features levels --test levels
