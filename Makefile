# inspect_pipe — two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
DATA   ?= ../shared/data
OUT    ?= out

.PHONY: install test demo bench clean chromium

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,base,mavlink,browser-test]' --config-settings editable_mode=compat
	touch $@

# The browser test drives Debian's Chromium (never a downloaded browser). Installed when apt can;
# otherwise that one test skips with the reason and the target still succeeds.
chromium:
	@command -v chromium >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && apt-get install -y -qq chromium chromium-driver) >/dev/null 2>&1; } \
	  || echo "chromium not installed: the browser test will skip"


install: $(VENV)/.installed

test: $(VENV)/.installed chromium
	$(PY) -m pytest

demo: $(VENV)/.installed
	$(VENV)/bin/inspect-pipe mosaic $(DATA)/mosaic/synth_rust_sweep/frames -o $(OUT)/demo_mosaic

bench: $(VENV)/.installed
	$(PY) -m bench --data $(DATA)

clean:
	rm -rf $(OUT) .pytest_cache
