# dcrt: `make demo` renders the default scene, `make test` runs every check.
CARGO ?= cargo
# Open MPI refuses to run as root without these; harmless otherwise.
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1

.PHONY: setup build demo test lint

setup:
	@bash scripts/setup.sh

build: setup
	$(CARGO) build --release

demo: build
	./target/release/dcrt render scenes/default.toml -o out.png
	@echo "demo: wrote $(CURDIR)/out.png"

lint: setup
	$(CARGO) fmt --check
	$(CARGO) clippy --release --all-targets -- -D warnings

test: lint
	$(CARGO) nextest run --release --profile ci
