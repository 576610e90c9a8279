# The two set-up commands of the README: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.facetex-installed
TEST_STAMP := $(VENV)/.facetex-test-installed
DEMO_OUT ?= demo_out

.PHONY: install demo test test-slow docs browser-deps bench clean

install: $(STAMP)

$(STAMP): pyproject.toml setup.py tools/install_torch.sh
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	bash tools/install_torch.sh $(PY)
	$(PY) -m pip install -q -e .
	touch $(STAMP)

# the test and Ray extras (~2 GB with Ray): only the tests need them, not the demo
$(TEST_STAMP): $(STAMP)
	$(PY) -m pip install -q -e '.[test,ray]'
	touch $(TEST_STAMP)

demo: $(STAMP)
	$(VENV)/bin/facetex demo --out $(DEMO_OUT)

test: $(TEST_STAMP)
	$(PY) -m pytest -q

test-slow: $(TEST_STAMP)
	# pytest exits 5 when no test is marked slow: that is not a failure
	$(PY) -m pytest -q -m slow || [ $$? -eq 5 ]

# the documentation site (docs/, mkdocs.yml) into site/; warnings are errors
docs: $(STAMP)
	$(PY) -m pip install -q -e '.[docs]'
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict -q

# Debian's Chromium for the report's browser test (tests/report/test_report_browser.py);
# CI runs this as root before the tests. Elsewhere: run it with sudo, or the test is skipped.
browser-deps:
	@if command -v chromium >/dev/null 2>&1; then chromium --version; \
	elif [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null && chromium --version; \
	else echo "make browser-deps: Chromium is missing; run 'sudo make browser-deps' (the browser test is skipped without it)"; fi

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache site
