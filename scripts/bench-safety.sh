#!/usr/bin/env bash
# The safety campaign at the motors, full size (host, release build):
#   scripts/bench-safety.sh [--runs N] [--cycles C]
# N randomized runs (default 12) of C cycles (default 30000) at each of
# 250 us, 1 ms, 10 ms and 100 us through hap_core::cycle::ServoCycle::run
# (default: 1.44*10^6 cycles), deterministic seeds. Every run asserts, on the torque
# the motors apply and on the handle's motion: coupling energy >= rounding,
# force/torque/speed bounds, link fade and ramps, torque 0 after a fail-safe
# cut (see Documentation/control.md). Prints the figures; a violated
# property stops the run with its seed and cycle. Mode: host native,
# deterministic (the figures do not depend on the host).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
. "$HERE/lib.sh"
runs=12; cycles=30000
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) hap_uint "$1" "${2-}"; runs=$2; shift ;;
    --cycles) hap_uint "$1" "${2-}"; cycles=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
  shift
done
cd "$ROOT/userspace"
cargo run --release -q -p hap-core --example safety_campaign -- "$runs" "$cycles"
