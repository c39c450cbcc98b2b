#!/usr/bin/env bash
# Builds kpcn and copies the binary into DIR, printing its path: the training and study
# scripts run that copy, so that rebuilding the crate during a long run does not swap the
# binary under it. The copy is renamed into place, so a run never sees half a file.
#
#   kpcn=$(scripts/pinned-kpcn.sh DIR)
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:?usage: scripts/pinned-kpcn.sh DIR}
mkdir -p "$dir"
cargo build --release --locked --quiet >&2
cp target/release/kpcn "$dir/kpcn.$$"
mv "$dir/kpcn.$$" "$dir/kpcn"
echo "$dir/kpcn"
