#!/usr/bin/env bash
# Install studyctl with its test extras into a fresh virtual environment and run the whole test suite.
# PostgreSQL's server binaries (initdb, pg_ctl) are installed from Debian when missing: the store
# tests start a throwaway server of their own and are never skipped. Chromium and chromedriver are installed
# the same way (scripts/ensure-browser.sh): the participant-view tests drive a real headless browser; and R
# (scripts/ensure-r.sh), so the test that reads the CSV export from R runs instead of being skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/ensure-postgres.sh
bash scripts/ensure-browser.sh
bash scripts/ensure-r.sh
venv="${STUDYCTL_TEST_VENV:-.venv-test}"
python3 -m venv "$venv"
# shellcheck disable=SC1091
. "$venv/bin/activate"
python -m pip install --quiet --upgrade pip
python -m pip install --quiet '.[test]'
# -m "": everything, slow tests included (plain `pytest` in a dev venv deselects them: see pyproject.toml)
pytest -m "" "$@"
