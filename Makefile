# Two commands do all their own set-up on a fresh clone:
#   make demo   creates .venv, installs the package, runs the main demo, writes an .rrd
#   make test   creates .venv, installs the package with its test extras, runs pytest on ti.cpu
# make view-check (not part of make test) runs every demo and screenshots its recording in Rerun's web viewer in
# headless Chromium (installs Debian's chromium if it is missing); the screenshots go to docs/
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
OUT ?= out

.PHONY: demo test bench view-check studio studio-check clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

demo: $(VENV)/.installed
	$(PY) demos/sew_tshirt.py --out $(OUT) --png

# two workers, one test file each at a time (a file's scenes share its module fixtures); TEST_WORKERS=0 runs serially
TEST_WORKERS ?= 2
test: $(VENV)/.installed
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile

bench: $(VENV)/.installed
	$(PY) -m taichi_cloth bench --out $(OUT)/bench

# Debian's Chromium, installed when missing (sudo unless root): view-check and studio-check drive it
NEED_CHROMIUM = command -v chromium >/dev/null 2>&1 || { $$(test "$$(id -u)" = 0 || echo sudo) apt-get update -qq && \
	$$(test "$$(id -u)" = 0 || echo sudo) apt-get install -y -qq chromium; }

$(VENV)/.view: $(VENV)/.installed
	$(PY) -m pip install --quiet -e '.[view]'
	touch $@

view-check: $(VENV)/.view
	$(NEED_CHROMIUM)
	$(PY) -m taichi_cloth.view_check --out $(OUT)/view --shots docs

# the pattern studio on the T-shirt's DXF (STUDIO_FILE=another file in demos/garments, or none): installs the
# `studio` extra first, then serves the page on 127.0.0.1:8765 until Ctrl-C
STUDIO_FILE ?= tshirt.dxf
$(VENV)/.studio-app: $(VENV)/.installed
	$(PY) -m pip install --quiet -e '.[studio]'
	touch $@

studio: $(VENV)/.studio-app
	cd demos/garments && ../../$(PY) -m taichi_cloth studio $(STUDIO_FILE)

# the pattern studio in a real browser (tests/test_studio_browser.py, marked `browser`; not part of make test): opens
# the T-shirt DXF, sews, places, saves and drapes it by clicking; the screenshots of each step go to docs/studio-*.png
$(VENV)/.studio: $(VENV)/.installed
	$(PY) -m pip install --quiet -e '.[studio,view]'
	touch $@

studio-check: $(VENV)/.studio
	$(NEED_CHROMIUM)
	STUDIO_SHOTS=docs $(PY) -m pytest -m browser -p no:xdist tests/test_studio_browser.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache *.egg-info
