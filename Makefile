# springc: the two commands a new user needs are `make demo` and `make test`.
PY ?= python3

.PHONY: install demo test bench clean

.installed: pyproject.toml scripts/install.sh
	bash scripts/install.sh
	touch .installed

install: .installed

demo: .installed
	$(PY) -m springc_cli.main demo

test: .installed
	$(PY) -m pytest -q

bench: .installed
	$(PY) -m springc_cli.main bench --out bench-out
	mkdir -p docs && cp bench-out/bench.md docs/bench.md

clean:
	rm -rf .installed out bench-out .pytest_cache
