#!/usr/bin/env bash
# Fuzz hap-core's frame decoder (protocol::decode, expected_len, and the
# decode -> encode -> decode fixed point of hap-core-fuzz's `check`):
#   scripts/fuzz.sh [--runs N] [--target NAME] [--plain] [--update-corpus]
# Targets (userspace/hap-core/fuzz/fuzz_targets/):
#   decode_frame      raw bytes into the decoder
#   decode_frame_crc  the same with magic, version and CRC-32C made valid
#                     first, so mutations reach the type/length/payload checks
# With cargo-fuzz and a nightly toolchain (rustup), runs each target (default:
# both) for N executions (default 10000000) under libFuzzer with debug
# assertions, hence overflow checks, on as in the kernel build
# (`cargo +nightly fuzz run -O -a`), starting from the committed seed corpus
# userspace/hap-core/fuzz/corpus/<target>/ (read-only); new inputs go to
# build/fuzz/corpus/<target>/, crashes to userspace/hap-core/fuzz/artifacts/.
# --update-corpus: afterwards minimise (cargo fuzz cmin) the union into the
# committed corpus directory. Without cargo-fuzz or nightly (or with --plain):
# the stable plain harness replays the committed corpus and runs N
# pseudo-random inputs (decode_plain, release build with overflow checks).
# Prints one summary line per target: executions, corpus size, crashes, wall time.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
FUZZ="$ROOT/userspace/hap-core/fuzz"
runs=10000000; targets=(); plain=0; update=0
die() { echo "fuzz.sh: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) [ $# -ge 2 ] || die "--runs needs a value"; runs=$2; shift ;;
    --target) [ $# -ge 2 ] || die "--target needs a value"; targets+=("$2"); shift ;;
    --plain) plain=1 ;;
    --update-corpus) update=1 ;;
    -h|--help) awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || die "--runs wants a positive integer, got '$runs'"
[ ${#targets[@]} -gt 0 ] || targets=(decode_frame decode_frame_crc)
for t in "${targets[@]}"; do
  [ -f "$FUZZ/fuzz_targets/$t.rs" ] || die "no fuzz target '$t' (see $FUZZ/fuzz_targets/)"
done

have_libfuzzer() {
  command -v cargo-fuzz >/dev/null 2>&1 || [ -x "$HOME/.cargo/bin/cargo-fuzz" ] || return 1
  command -v rustup >/dev/null 2>&1 || return 1
  rustup toolchain list 2>/dev/null | grep -q '^nightly' || return 1
}

if [ "$plain" = 1 ] || ! have_libfuzzer; then
  [ "$plain" = 1 ] || echo "fuzz.sh: cargo-fuzz or a nightly toolchain is missing: plain (stable) harness instead" >&2
  start=$(date +%s)
  cargo build --release -q --manifest-path "$FUZZ/Cargo.toml" --bin decode_plain
  bin="$FUZZ/target/release/decode_plain"
  nseed=0
  for t in "${targets[@]}"; do
    shopt -s nullglob; files=("$FUZZ/corpus/$t"/*); shopt -u nullglob
    if [ ${#files[@]} -gt 0 ]; then
      "$bin" "${files[@]}" >/dev/null
      nseed=$((nseed + ${#files[@]}))
    fi
  done
  "$bin" "$runs" >/dev/null
  echo "fuzz: decode_plain (stable, no coverage feedback): $runs random inputs + $nseed corpus files, 0 crashes, $(( $(date +%s) - start )) s wall"
  exit 0
fi

cd "$ROOT/userspace/hap-core"
fail=0
for t in "${targets[@]}"; do
  seeds="$FUZZ/corpus/$t"; work="$ROOT/build/fuzz/corpus/$t"
  mkdir -p "$seeds" "$work"
  log="$ROOT/build/fuzz/$t.log"
  start=$(date +%s)
  set +e
  cargo +nightly fuzz run -O -a "$t" "$work" "$seeds" -- \
    -runs="$runs" -max_len=128 -print_final_stats=1 >"$log" 2>&1
  rc=$?
  set -e
  wall=$(( $(date +%s) - start ))
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  if [ "$rc" != 0 ]; then
    fail=1
    echo "fuzz: $t FAILED (rc=$rc) after $wall s; log: $log; artifacts:" >&2
    ls "$FUZZ/artifacts/$t" >&2 2>/dev/null || true
    grep -E 'panicked|SUMMARY|ERROR' "$log" | head -5 >&2 || true
    continue
  fi
  if [ "$update" = 1 ]; then
    # cmin minimises its corpus directory in place: the union of the seeds
    # and the new inputs, then back into the committed directory.
    tmp="$ROOT/build/fuzz/cmin-$t"; rm -rf "$tmp"; mkdir -p "$tmp"
    cp "$seeds"/* "$work"/* "$tmp"/ 2>/dev/null || true
    cargo +nightly fuzz cmin -O -a "$t" "$tmp" >"$ROOT/build/fuzz/$t.cmin.log" 2>&1
    rm -f "$seeds"/*; cp "$tmp"/* "$seeds"/
  fi
  nwork=$(find "$work" -type f | wc -l); nseeds=$(find "$seeds" -type f | wc -l)
  cov=$(grep -E '^#[0-9]+.*DONE' "$log" | tail -1 | sed -E 's/.*cov: ([0-9]+).*ft: ([0-9]+).*/cov \1, ft \2/')
  echo "fuzz: $t (libFuzzer, cargo +nightly fuzz run -O -a): ${execs:-?} executions, $wall s wall, 0 crashes; corpus: $nseeds committed + $nwork new in build/fuzz; $cov"
done
exit "$fail"
