#!/usr/bin/env bash
# Install Debian packages, waiting (bounded) while another apt/dpkg process (unattended upgrades, a second install)
# holds the package locks: usage `bash scripts/apt-install.sh PACKAGE...`.
# `install` waits by itself (DPkg::Lock::Timeout), but apt 2.6's `update` ignores that option and fails at once on
# the lists lock, so `update` is retried here until it gets the lock or the wait is over.
set -euo pipefail
wait_s="${STUDYCTL_APT_WAIT_S:-600}"
retry_s="${STUDYCTL_APT_RETRY_S:-5}"
export DEBIAN_FRONTEND=noninteractive
deadline=$((SECONDS + wait_s))
told=""
while true; do
    if out=$(apt-get -o DPkg::Lock::Timeout="$wait_s" update -qq 2>&1); then
        break
    fi
    if ! grep -qiE "could not get lock|unable to lock|unable to acquire" <<<"$out" || [ "$SECONDS" -ge "$deadline" ]; then
        echo "$out" >&2
        if [ "$SECONDS" -ge "$deadline" ]; then
            echo "apt-get update: the package lists were still locked after ${wait_s} s (another apt or dpkg is running;" \
                 "wait for it, or set STUDYCTL_APT_WAIT_S)" >&2
        fi
        exit 1
    fi
    if [ -z "$told" ]; then
        echo "apt-get update: the package lists are locked by another apt or dpkg; waiting (up to ${wait_s} s)" >&2
        told=1
    fi
    sleep "$retry_s"
done
left=$((deadline - SECONDS))
apt-get -o DPkg::Lock::Timeout="$((left > 0 ? left : 1))" install -y -qq "$@" >/dev/null
