#!/usr/bin/env bash
# `balanced`'s steps after the network, each metadata only (the weights kept bit for bit but
# for the first): f16 (`kpcn model half`), the `significant` firefly clamp, the specular bound
# of 2 standard errors, the diffuse ceiling of CEILING standard errors (default 2; 0: none)
# and the diffuse detail restored over 15x15 windows (models/README.md says why each).
# The one home of that sequence for the scripts that ship `balanced` and `fast`.
#
#   scripts/steps-after-network.sh KPCN IN OUT [CEILING]   # KPCN: the kpcn binary to run
set -euo pipefail
kpcn=${1:?usage: scripts/steps-after-network.sh KPCN IN OUT [CEILING]}
in=${2:?IN}
out=${3:?OUT}
ceiling=${4:-2}
"$kpcn" model half "$in" -o "$out"
"$kpcn" model clamp "$out" --clamp significant -o "$out"
"$kpcn" model bound "$out" --branch specular --errors 2 -o "$out"
"$kpcn" model bound "$out" --branch diffuse --errors "$ceiling" -o "$out"
"$kpcn" model detail "$out" --radius 7 -o "$out"
