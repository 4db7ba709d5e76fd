# Set-up and entry points. `make run` and `make test` work on a fresh machine:
# they create .venv, install the pinned Python dependencies (constraints.txt),
# the npm assets of the dashboard (web/package-lock.json) and, when run as root,
# the Debian packages the browser test needs (chromium).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: setup web-deps run test test-fast schema lint typecheck pytest reproduce bench docs system-deps clean \
        image run-image test-image

setup: $(STAMP) web-deps

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]'
	touch $@

# the dashboard's npm packages (uPlot), from web/package-lock.json
web-deps:
	@if [ -f web/package-lock.json ]; then \
	  if [ ! -f web/node_modules/.stamp ] || [ web/package-lock.json -nt web/node_modules/.stamp ]; then \
	    (cd web && npm ci --no-audit --no-fund --loglevel=error) && touch web/node_modules/.stamp; \
	  fi; \
	fi

# Debian packages the tests use: chromium (browser test), mosquitto (the MQTT broker the
# broker tests start on a free loopback port). Installed only when missing, only as root.
system-deps:
	@missing=""; \
	[ -x /usr/bin/chromium ] || missing="$$missing chromium"; \
	[ -x /usr/sbin/mosquitto ] || missing="$$missing mosquitto"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = "0" ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing) >/dev/null; \
	  else echo "note: missing$$missing and not root; the tests that need them will be skipped"; fi; \
	fi

run: setup
	$(BIN)/cutwatch serve

reproduce: setup
	$(BIN)/cutwatch reproduce --all

bench: setup
	$(BIN)/cutwatch bench

# the dashboard's stream schema (web/schema.js) from the message models
# (server/service/messages.py); tests/service/test_protocol.py fails while it is stale
schema: setup
	$(BIN)/cutwatch schema --js --out web/schema.js

# the documentation (docs/, mkdocs.yml) as a site in site/; any warning fails the build
docs: setup
	$(BIN)/mkdocs build --strict --site-dir site

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

typecheck: setup
	$(BIN)/mypy

pytest: setup system-deps
	$(BIN)/python -m pytest

test: lint typecheck pytest

# The fast loop: the unit and property tests, without the tests that start a server, a
# broker or a browser, or run a reproduction (marks in tests/conftest.py; about a fifth of
# the full suite's time or less, see docs/development.md)
FAST := not slow and not server and not broker and not browser and not image
test-fast: setup
	$(BIN)/python -m pytest -q -m '$(FAST)'

# The container image (Dockerfile), built and run without a daemon by buildah (as root;
# installs buildah and debootstrap when missing). docs/deploy.md has the Docker commands.
image:
	deploy/build-image.sh

# PORT (8000), VISER_PORT (8080), CUTWATCH_TOKEN (generated when unset); Ctrl-C stops it
run-image:
	deploy/run-image.sh

# builds the image and runs it (tests/deploy, marked `image`; not part of `make test`)
test-image: setup
	$(BIN)/python -m pytest -m image tests/deploy

clean:
	rm -rf $(VENV) web/node_modules
