# inspect_pipe — two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
DATA   ?= ../shared/data
OUT    ?= out

EXTRAS := test,base,mavlink,import,browser-test,report,dask,campaign

.PHONY: install test demo bench clean chromium pdfdeps lock lock-upgrade

# pyproject.toml gives compatible ranges (installable beside other packages); requirements.lock pins
# every package of those extras, with hashes, for reproducible installs. The project itself goes
# in after, without touching the locked set.
$(VENV)/.installed: pyproject.toml requirements.lock
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.lock
	$(PY) -m pip install -q --no-deps -e '.[$(EXTRAS)]' --config-settings editable_mode=compat
	touch $@

# Regenerate requirements.lock after a change of pyproject.toml's dependencies: versions already
# locked are kept (lock-upgrade takes the newest within the ranges).
lock:
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q 'pip-tools>=7.6,<8'
	$(VENV)/bin/pip-compile --quiet --extra $(EXTRAS) --generate-hashes --strip-extras --no-emit-index-url \
	  --no-emit-find-links --output-file requirements.lock pyproject.toml

lock-upgrade:
	rm -f requirements.lock
	$(MAKE) lock

# The browser test drives Debian's Chromium (never a downloaded browser). Installed when apt can;
# otherwise that one test skips with the reason and the target still succeeds.
chromium:
	@command -v chromium >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && apt-get install -y -qq chromium chromium-driver) >/dev/null 2>&1; } \
	  || echo "chromium not installed: the browser test will skip"


# report.pdf (WeasyPrint) needs Pango; the PDF test renders pages with pdftoppm (poppler-utils).
# Installed when apt can; otherwise the PDF is skipped with a message and its test skips.
pdfdeps:
	@{ command -v pdftoppm >/dev/null 2>&1 && ldconfig -p 2>/dev/null | grep -q libpangoft2; } || \
	  { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && apt-get install -y -qq poppler-utils libpango-1.0-0 libpangoft2-1.0-0 fonts-dejavu-core) >/dev/null 2>&1; } \
	  || echo "poppler-utils/Pango not installed: report.pdf and its test will be skipped"

install: $(VENV)/.installed

test: $(VENV)/.installed chromium pdfdeps
	$(PY) -m pytest

demo: $(VENV)/.installed pdfdeps
	$(VENV)/bin/inspect-pipe demo -o $(OUT)/demo --data $(DATA)

bench: $(VENV)/.installed
	$(PY) -m bench --data $(DATA)

clean:
	rm -rf $(OUT) .pytest_cache
