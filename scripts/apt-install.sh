#!/usr/bin/env bash
# Installs the Debian packages named on the command line that are not installed yet (one
# `apt-get update` first, only when something is missing); uses sudo when not root. The one
# way the test scripts install system packages:
#
#   bash scripts/apt-install.sh cmake g++ libmsgpack-cxx-dev
set -euo pipefail
missing=()
for pkg in "$@"; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$pkg")
    fi
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "== installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
