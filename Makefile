# by_your_command: `make demo` runs the offline demo, `make test` runs every test.
# Both bootstrap the checkout first (system packages, .venv with ROS 2 Jazzy, colcon build).
# `make lint` also checks that the package needs nothing newer than Python 3.10 (vermin).
SHELL := /bin/bash
RUN := scripts/run.sh

.PHONY: all bootstrap demo test unit lint format bench soak clean distclean

all: test

bootstrap:
	@scripts/bootstrap.sh

# make demo PROVIDER=openai|gemini|gpt-live: the cloud agent (needs OPENAI_API_KEY / GEMINI_API_KEY;
# gpt-live: OPENAI_API_KEY, full duplex with the echo-cancelled microphone)
PROVIDER ?= offline
demo: bootstrap
	@$(RUN) byc demo --provider $(PROVIDER)

test: bootstrap lint
	@scripts/run_tests.sh

unit: bootstrap
	@scripts/run_tests.sh -m unit

lint: bootstrap
	@$(RUN) ruff check .
	@$(RUN) ruff format --check .
	@$(RUN) mypy
	@$(RUN) vermin --target=3.10- --no-tips --violations --eval-annotations --quiet \
	  by_your_command/by_your_command by_your_command/setup.py scripts bench

format: bootstrap
	@$(RUN) ruff check --fix .
	@$(RUN) ruff format .

# every bench/bench_*.py; the figures also go to out/bench/summary.{md,json}
bench: bootstrap
	@$(RUN) python bench/run_all.py

# an hour of conversation compressed into ~16 minutes: memory, CPU, losses, billed seconds
soak: bootstrap
	@$(RUN) python bench/soak.py

clean:
	rm -rf build install log .pytest_cache .mypy_cache .ruff_cache .hypothesis
	find . -name __pycache__ -type d -prune -not -path './.venv/*' -exec rm -rf {} +

distclean: clean
	rm -rf .venv
