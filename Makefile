# inspect_pipe — two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
DATA   ?= ../shared/data
OUT    ?= out

.PHONY: install test demo bench clean

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]' --config-settings editable_mode=compat
	touch $@

install: $(VENV)/.installed

test: $(VENV)/.installed
	$(PY) -m pytest

demo: $(VENV)/.installed
	$(VENV)/bin/inspect-pipe mosaic $(DATA)/mosaic/synth_rust_sweep/frames -o $(OUT)/demo_mosaic

bench: $(VENV)/.installed
	$(PY) -m bench --data $(DATA)

clean:
	rm -rf $(OUT) .pytest_cache
