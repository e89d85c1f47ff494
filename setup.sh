#!/usr/bin/env bash
# One-time set-up on a fresh machine: the system libraries that off-screen rendering needs
# (Debian/Ubuntu, installed only when missing and when we are root) and afmsim itself with its
# test extras. Safe to run again: it installs nothing that is already there.
set -euo pipefail
cd "$(dirname "$0")"

if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  missing=""
  for pkg in libegl1 libgl1-mesa-dri; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
  done
  if [ -n "$missing" ]; then
    echo "setup: installing off-screen rendering libraries:$missing"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  fi
fi

python3 -m pip install --quiet --disable-pip-version-check -e '.[test]'
