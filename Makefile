# The two commands a newcomer needs: `make run` (default pipeline) and `make test`.
# Rules call `python`: the venv comes first on PATH (or a conda env with --use-conda).
export PATH := $(CURDIR)/.venv/bin:$(PATH)
SNAKEMAKE := snakemake
PYTEST := pytest
# Two workers; a module's tests and the tests of the end-to-end run are each one unit (tests/conftest.py).
PYTEST_WORKERS := -n 2 --dist loadscope --no-loadscope-reorder

.PHONY: setup run test test-fast bench lint clean

setup:
	bash scripts/setup.sh

run: setup
	$(SNAKEMAKE)

test:
	bash scripts/setup.sh --test
	$(PYTEST) -q -rs --durations=25 $(PYTEST_WORKERS) --junitxml=results/tests/junit.xml

test-fast: setup
	$(PYTEST) -q -m "not slow" $(PYTEST_WORKERS)

bench: setup
	.venv/bin/python benchmarks/run_all.py

lint: setup
	$(SNAKEMAKE) --lint
	.venv/bin/snakefmt --check Snakefile workflow/rules

clean:
	rm -rf results logs .snakemake
