# Set-up is part of every target: a fresh clone needs only `make demo` or `make test`.
VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed-stamp
DEMO    := demo

.PHONY: install test lint demo clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,nn,dask]"
	# the franka source's tests need a simulated robot; they skip where it does not install
	-$(PY) -m pip install --quiet -e ".[sim-robot]" || echo "franky-sim/pylibfranka not installable here: franka source tests will skip"
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

test: $(STAMP) lint
	$(PY) -m pytest -q -n 2 -m "not slow"

# Record a simulated adjust on link 5, show it, replay it through the default model
# (built and cached on first use) into demo.rrd, and open the viewer when there is a display.
demo: $(STAMP)
	@mkdir -p $(DEMO)
	@session=$$($(VENV)/bin/recorder capture --pose B --action adjust --link 5 --seed 7 \
	    --out $(DEMO) --overwrite) \
	  && echo "recorded $$session" \
	  && $(VENV)/bin/recorder info $$session \
	  && $(VENV)/bin/replay $$session --viewer rerun --save demo.rrd

clean:
	rm -rf $(DEMO) demo.rrd .pytest_cache .ruff_cache
