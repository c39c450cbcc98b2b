#!/usr/bin/env bash
# Installs the Debian packages kpcn builds against. Idempotent: installs only what is
# missing and touches nothing (not even apt's lists) when everything is present.
set -euo pipefail

# fonts-dejavu-core: the text of training and study plots.
packages=(libopenimageio-dev libclang-dev pkg-config g++ fonts-dejavu-core)

missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if ((${#missing[@]} == 0)); then
    exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then
    sudo="sudo"
fi
echo "kpcn setup: installing ${missing[*]}" >&2
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "kpcn setup: done" >&2
