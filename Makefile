# Two commands do everything on a fresh machine (see README.md):
#   make demo   set up, then generate the tiny suite, train every variant of it, score the runs, print the table
#   make test   set up, then run the test suite (what CI runs)
SHELL := /bin/bash
export OMP_WAIT_POLICY ?= PASSIVE
export DRJIT_LIBLLVM_PATH ?= $(firstword $(wildcard /usr/lib/x86_64-linux-gnu/libLLVM.so.19*))
VENV := .venv/bin
OUT ?= out

.PHONY: setup demo test test-slow lint format results clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/m4dgs-eval suite run tiny --preset tiny --root $(OUT)
	$(VENV)/m4dgs-eval report table tiny --root $(OUT)

test: setup
	$(VENV)/python -m pytest

lint: setup
	$(VENV)/ruff format --check .
	$(VENV)/ruff check .

format: setup
	$(VENV)/ruff format .
	$(VENV)/ruff check --fix .

# both results pages from their committed CSVs (each page states the command that makes it): the
# results page in docs/, the superseded generator-5 one in the research record, lab/
results: setup
	$(VENV)/m4dgs-eval report results
	$(VENV)/m4dgs-eval report results --csv results/runs-generator5.csv --out lab/results-generator5.md \
		--no-readme --title 'Results on the generator-5 benchmark (superseded)'

test-slow: setup
	$(VENV)/python -m pytest -m slow

clean:
	rm -rf $(OUT) .pytest_cache
