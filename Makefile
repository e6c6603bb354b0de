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

# measures (about 40 min on 2 cores); the page alone again from its numbers:
# springc bench --render docs/bench/bench.json --out docs
bench: install
	$(VENV)/bin/springc bench --out bench-out
	mkdir -p docs/bench && cp bench-out/bench.md docs/bench.md
	cp bench-out/bench/bench.json bench-out/bench/*.png docs/bench/

clean:
	rm -rf .venv out bench-out .pytest_cache
