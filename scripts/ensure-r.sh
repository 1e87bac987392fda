#!/usr/bin/env bash
# Make R (Debian's r-base-core, with jsonlite) available for the test that reads the CSV export from R
# (tests/engine/test_export_readers.py): without it that test would be skipped on every CI run.
# --no-install-recommends: Rscript alone is 7 packages; with recommends it is ~650 (X11, compilers, LaTeX).
set -euo pipefail
if command -v Rscript >/dev/null 2>&1 && Rscript -e 'library(jsonlite)' >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "R or its jsonlite package is missing; run: sudo apt-get install --no-install-recommends r-base-core r-cran-jsonlite" >&2
    exit 1
fi
# Another apt/dpkg process may hold the package locks: apt-install.sh waits for them, bounded.
bash "$(dirname "$0")/apt-install.sh" --no-install-recommends r-base-core r-cran-jsonlite
