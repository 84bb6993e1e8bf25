# Everything a fresh machine needs: a virtual environment with the package
# installed in it. `make demo` runs the main job, `make test` the tests.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test bench protos clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all,test,bench]'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m caveclod.cli demo

# A process per core (at most 4), each test file on one of them: the suite's servers and browsers
# mostly wait, so two processes on a 2-core machine halve its time (16.6 -> 8.2 min from a fresh
# checkout, whose kernels compile on first use; 9.9 -> 5.1 min once compiled).
test: $(STAMP)
	$(PY) -m pytest -q -n auto --maxprocesses=4 --dist loadfile

# Regenerate the committed caveclod.v1 stubs after editing the .proto;
# tests/test_stubs.py fails while they are stale.
protos: $(STAMP)
	$(PY) -m grpc_tools.protoc -I protos --python_out=. --pyi_out=. --grpc_python_out=. caveclod/v1/caveclod.proto

bench: $(STAMP)
	$(PY) benchmarks/build.py

clean:
	rm -rf $(VENV) out .pytest_cache
