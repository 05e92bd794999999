# Set-up is part of every target: a fresh clone needs only `make demo` or `make test`.
VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed-stamp
DEMO    := demo

CHECK   := viewer-check
SHOTS   := build/screenshots
GAZ     := ../shared/reference/gaz2019-exciting-traj

TYPES   := build/typecheck

.PHONY: install test check lint typecheck model docs demo viewer-check chromium clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,nn,browser,dask,notebook]"
	# the franka source's tests need a simulated robot; they skip where it does not install
	-$(PY) -m pip install --quiet -e ".[sim-robot]" || echo "franky-sim/pylibfranka not installable here: franka source tests will skip"
	# the documentation site's tools; `make docs` skips the build where they do not install
	-$(PY) -m pip install --quiet -e ".[docs]" || echo "mkdocs not installable here: make docs will skip"
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# mypy on every package, strict on schemas, robots and util ([tool.mypy] in pyproject.toml).
# The top-level folders become subpackages of contactkit through setuptools' package-dir,
# which mypy cannot follow, so it reads a link tree that puts them where their import names
# say: build/typecheck/contactkit/ links every entry of contactkit/ and the five folders.
typecheck: $(STAMP)
	@rm -rf $(TYPES)/contactkit && mkdir -p $(TYPES)/contactkit
	@for entry in contactkit/*; do ln -s ../../../$$entry $(TYPES)/contactkit/; done
	@for pkg in schemas features classify recorder replay; do \
	  ln -s ../../../$$pkg $(TYPES)/contactkit/$$pkg; done
	cd $(TYPES) && ../../$(PY) -m mypy --config-file ../../pyproject.toml

# The fast loop: lint, types and the unit tests, without the docs, the browser, torch/onnx
# (the nn marker) or slow tests; a few minutes on 2 cores.
check: lint typecheck
	$(PY) -m pytest -q -n 2 -p no:cacheprovider -m "not slow and not browser and not nn and not docs" \
	  --durations=10

# The default model is built (and cached) before the unit tests, on both cores, so that
# no test's fixture builds it under the per-test timeout while the other worker runs tests.
# The notebooks (the docs marker) and the browser checks run alone, after the rest: a
# notebook's kernel maps its jobs on a pool of its own, whose workers spun at full CPU
# in two full parallel runs (never alone, beside the other notebook or under load).
test: $(STAMP) lint typecheck chromium model
	$(PY) -m pytest -q -n 2 -m "not slow and not browser and not docs" --durations=25
	@$(MAKE) --no-print-directory docs
	$(PY) -m pytest -q -m "(browser or docs) and not slow" --durations=10

# The default model (built from its recipe once, then cached; a few minutes on 2 cores).
model: $(STAMP)
	$(VENV)/bin/replay --build-default-model

# The documentation site (mkdocs.yml, docs/): strict, so a broken link or reference fails.
# The command reference and the session format are generated at build time (docs/hooks.py);
# the screenshots of the view are taken afresh from the demo replay by the browser check
# (docs/screenshots.py; without a browser the site keeps the committed ones and says so).
docs: $(STAMP) demo chromium
	@rm -f $(SHOTS)/demo.png
	@if $(PY) -c "import mkdocs, material, mkdocstrings_handlers.python" 2>/dev/null; then \
	  $(PY) tools/viewer_check.py demo.rrd --cursor 0.5 --timeout 200 --out $(SHOTS) \
	    || echo "the browser check did not screenshot the demo replay (above)"; \
	  NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet --site-dir site; \
	else echo "mkdocs, mkdocs-material or mkdocstrings not installed: docs build skipped"; fi

# The browser check needs a system Chromium: installed here when running as root with
# apt-get; otherwise (or when that fails) the browser test skips and says why.
chromium:
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null \
	  || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
	       && (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	           chromium >/dev/null) ; } \
	  || echo "chromium not installed: the browser check will be skipped"

# Record a simulated adjust on link 5, show it, replay it through the default model
# (built and cached on first use) into demo.rrd, and open the viewer when there is a display.
demo: $(STAMP)
	@mkdir -p $(DEMO)
	@session=$$($(VENV)/bin/recorder capture --pose B --action adjust --link 5 --seed 7 \
	    --out $(DEMO) --overwrite) \
	  && echo "recorded $$session" \
	  && $(VENV)/bin/recorder info $$session \
	  && $(VENV)/bin/replay $$session --viewer rerun --save demo.rrd --overwrite

# Open the demo replay, a replay of the real Gaz et al. log (imported as a session) and a
# stats report in headless Chromium; fail on any viewer error. Screenshots in $(CHECK)/.
viewer-check: demo chromium
	@rm -rf $(CHECK)/real && mkdir -p $(CHECK)
	@real=$$($(VENV)/bin/recorder import-arrays --t $(GAZ)/time.txt --q $(GAZ)/positions.txt \
	    --dq $(GAZ)/velocity.txt --tau $(GAZ)/torques.txt --meta with_hand=false \
	    --meta planned_at_s=10 --out $(CHECK)/real) \
	  && $(VENV)/bin/replay $$real --viewer none --save $(CHECK)/real.rrd --overwrite \
	  && $(VENV)/bin/recorder stats $(DEMO) --out $(CHECK)/report --overwrite \
	  && $(PY) tools/viewer_check.py demo.rrd $(CHECK)/real.rrd \
	       --report $(CHECK)/report.html --out $(CHECK)

clean:
	rm -rf $(DEMO) demo.rrd $(CHECK) site .pytest_cache .ruff_cache
