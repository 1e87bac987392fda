#!/usr/bin/env bash
# Make PostgreSQL's server binaries available for the test suite (Debian package `postgresql`).
set -euo pipefail
if command -v initdb >/dev/null 2>&1 || compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "PostgreSQL server binaries are missing; run: sudo apt-get install postgresql" >&2
    exit 1
fi
# Another apt/dpkg process may hold the package locks: apt-install.sh waits for them, bounded.
bash "$(dirname "$0")/apt-install.sh" postgresql
