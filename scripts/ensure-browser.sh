#!/usr/bin/env bash
# Make Debian's Chromium and its WebDriver available for the participant-view tests and `studyctl bench view`
# (packages `chromium` and `chromium-driver`: /usr/bin/chromium, /usr/bin/chromedriver).
set -euo pipefail
if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "Chromium or chromedriver is missing; run: sudo apt-get install chromium chromium-driver" >&2
    exit 1
fi
# Another apt/dpkg process may hold the package locks: apt-install.sh waits for them, bounded.
bash "$(dirname "$0")/apt-install.sh" chromium chromium-driver
