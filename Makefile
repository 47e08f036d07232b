# Two commands for users: `make demo` and `make test`. Both set up a virtual environment on
# first use (Python 3.11, ROS 2 Jazzy from PyPI wheels) and reuse it afterwards.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.setup-stamp
DEMO_BAG ?= bags/exp1_stationary_single_walker
DEMO_OUT ?= out/demo

.PHONY: setup demo test bench bags clean

setup: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[wheels,tools,train,test,bench]'
	touch $(STAMP)

demo: setup
	$(BIN)/laser-tracker demo $(DEMO_BAG) --out $(DEMO_OUT)

test: setup
	$(BIN)/python -m pytest -q -p no:cacheprovider test

bench: setup
	$(BIN)/laser-tracker bench all

bags: setup
	$(BIN)/laser-tracker simulate all bags --overwrite

clean:
	rm -rf $(VENV) build install log out *.egg-info
