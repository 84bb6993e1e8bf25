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

test: $(STAMP)
	$(PY) -m pytest -q

# Regenerate the committed caveclod.v1 stubs after editing the .proto;
# tests/test_stubs.py fails while they are stale.
protos: $(STAMP)
	$(PY) -m grpc_tools.protoc -I protos --python_out=. --pyi_out=. --grpc_python_out=. caveclod/v1/caveclod.proto

bench: $(STAMP)
	$(PY) benchmarks/build.py

clean:
	rm -rf $(VENV) out .pytest_cache
