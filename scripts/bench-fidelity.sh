#!/usr/bin/env bash
# What the hand feels (host, release build, deterministic):
#   scripts/bench-fidelity.sh [--out DIR] [--only SECTION]
# Through hap_core::cycle::ServoCycle::run with a MotorLine and the simulated
# arm, per period (100 us, 250 us, 1 ms, 10 ms): the felt stiffness of a
# rigid wall at 5, 10 and 25 N at three poses and three axes next to the
# motors' force capacity there, the penetration curve, the wall's return
# after a push beyond the capacity, the drag of free motion at 0.1, 0.5 and
# 1 m/s with the client's object following every 3 ms, the largest powered
# handle speed under a 25 N push, the largest force step in one cycle per
# cause, and the passive stiffness x damping region per period (Z-width,
# DIR/zwidth.svg). SECTION: stiffness, recovery, drag, speed, steps, zwidth.
# Prints the figures (Markdown) and writes them to DIR/fidelity.md
# (default build/bench-fidelity). Mode: host native, deterministic.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
. "$HERE/lib.sh"
out="$ROOT/build/bench-fidelity"; only=()
while [ $# -gt 0 ]; do
  case "$1" in
    --out) [ -n "${2-}" ] || die "--out needs a directory"; out=$2; shift ;;
    --only) [ -n "${2-}" ] || die "--only needs a section (see --help)"; only=(--only "$2"); shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
  shift
done
mkdir -p "$out"
out=$(cd "$out" && pwd)
cd "$ROOT/userspace"
cargo build --release -q -p hap-core --example fidelity
./target/release/examples/fidelity --svg "$out" "${only[@]}" | tee "$out/fidelity.md"
log "figures: $out/fidelity.md"
