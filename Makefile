# The two README commands: `make demo` and `make test`. Each one creates or refreshes the
# project's virtual environment (.venv) from constraints.txt, the exact versions that passed.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    := out

.PHONY: demo test lint lock clean venv

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(STAMP)

# One OpenBLAS thread per test worker (two workers on two cores; the CLI sets the same default).
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -n 2 --dist loadfile -q

demo: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/rlgp-exec demo --out $(OUT)

lint: $(STAMP)
	$(BIN)/ruff check rlgp_exec robots perception sim tests tools examples
	$(BIN)/mypy
	$(BIN)/lint-imports

# Re-record the exact versions after a deliberate upgrade (then run `make test`).
lock:
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m pip freeze --exclude-editable | grep -v '^rlgp-exec' > constraints.txt
	touch $(STAMP)

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache
