# Lightwire: the two commands.
#
#   make run   installs what is missing, builds, serves the default scene
#   make bake  the same, but bakes the default scene once to $(OUT)
#   make test  installs what is missing, runs every test (Rust, the
#              dashboard's JavaScript, and the dashboard in headless Chromium)
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

.PHONY: run bake test deps check-toolchain build dashboard-deps

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
	@echo "$(OUT)/atlas.json maps surfaces to atlas rectangles, $(OUT)/stats.json has the numbers."

# The dashboard's browser test (server/tests/dashboard.rs) runs inside
# `cargo test`; its screenshots land in target/dashboard-artifacts/.
test: deps dashboard-deps
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	cd $(DASHBOARD) && node --test test/
	$(CARGO) test --workspace
