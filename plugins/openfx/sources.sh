#!/usr/bin/env bash
# Prints the folder of the OpenFX sources (include/, HostSupport/) that openfx-sys
# carries, fetching the crate first when needed.
set -euo pipefail
manifest="$(cd "$(dirname "$0")" && pwd)/Cargo.toml"
cargo fetch --locked --quiet --manifest-path "$manifest"
cargo metadata --locked --format-version 1 --manifest-path "$manifest" |
    python3 -c 'import json, os, sys
m = json.load(sys.stdin)
p = next(p for p in m["packages"] if p["name"] == "openfx-sys")
print(os.path.join(os.path.dirname(p["manifest_path"]), "openfx"))'
