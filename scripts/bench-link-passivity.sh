#!/usr/bin/env bash
# The link passivity campaign, full size (host, release build):
#   scripts/bench-link-passivity.sh [--runs N] [--cycles C] [--out DIR]
# The controller (hap_core::proto_in::ProtoIn + hap_core::cycle::ServoCycle,
# the simulated arm) and a client (hap_core::link::ClientLink, a 0.5 kg
# object, free or behind a 20 kN/m wall) exchange encoded frames through an
# in-process channel: round trips 0, 20, 100, 300, 1000 ms, jitter ±50 %
# (which reorders), loss 10 % and 20 %; N runs (default 6) of C cycles
# (default 20000) per case, random user efforts then a release: 2.16*10^6
# cycles by default. Every run asserts: the channel's energy (both ends'
# observers) >= -1e-4 J, force and speed bounds, no growing oscillation
# after the release, no fade of a live link. Prints per case the lowest
# channel energy, the share of cycles each passivity controller acted, the
# drift and the release's decay; the same link with the controllers off;
# and the wall probe (felt stiffness, penetration at 10 N, drift) per
# delay, plotted to DIR/link-probe.svg (default build/bench-link-passivity).
# Mode: host native, deterministic (the figures do not depend on
# the host). See Documentation/control.md, "Passivity across the link".
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
. "$HERE/lib.sh"
runs=6; cycles=20000; out="$ROOT/build/bench-link-passivity"
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) hap_uint "$1" "${2-}"; runs=$2; shift ;;
    --cycles) hap_uint "$1" "${2-}"; cycles=$2; shift ;;
    --out) [ -n "${2-}" ] || die "--out needs a directory"; out=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
  shift
done
mkdir -p "$out"; out=$(cd "$out" && pwd)
cd "$ROOT/userspace"
cargo run --release -q -p hap-core --example link_passivity -- "$runs" "$cycles" "$out"
