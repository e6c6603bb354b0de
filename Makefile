# springc: the two commands a new user needs are `make demo` and `make test`. Both install first:
# Debian packages, then a virtual environment in $(VENV) with springc and its dependencies.
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: install demo test bench clean

$(VENV)/.installed: pyproject.toml scripts/install.sh
	bash scripts/install.sh $(VENV)
	touch $@

install: $(VENV)/.installed

demo: install
	$(VENV)/bin/springc demo

test: install
	PATH="$(abspath $(VENV))/bin:$$PATH" $(PY) -m pytest -q -n auto --dist loadfile --durations=25

bench: install
	$(VENV)/bin/springc bench --out bench-out
	mkdir -p docs && cp bench-out/bench.md docs/bench.md

clean:
	rm -rf .venv out bench-out .pytest_cache
