#!/usr/bin/env bash
# Installs a pinned Python tool from PyPI into its own virtual environment,
# ~/.cache/kpcn/NAME (Debian's Python refuses pip installs outside one), unless
# `NAME --version` there already prints VERSION_LINE; prints the environment's bin folder.
#
#   scripts/venv-tool.sh NAME REQUIREMENT VERSION_LINE
#   e.g. scripts/venv-tool.sh maturin maturin==1.9.6 "maturin 1.9.6"
set -euo pipefail
name=${1:?NAME} requirement=${2:?REQUIREMENT} expected=${3:?VERSION_LINE}
venv=${XDG_CACHE_HOME:-$HOME/.cache}/kpcn/$name
if ! "$venv/bin/$name" --version 2>/dev/null | grep -qxF "$expected"; then
    echo "kpcn setup: installing $requirement into $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check "$requirement"
fi
echo "$venv/bin"
