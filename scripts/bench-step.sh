#!/usr/bin/env bash
# Host-side, repeatable cost of one SERVO cycle (issue 6, first slice):
#   scripts/bench-step.sh [--no-rt] [--rt-seconds S] [--period-us P]
# (a) callgrind: instructions per full cycle (hap_core::cycle::ServoCycle +
#     answer encoding + log record), = (Ir(K=2000) - Ir(K=1000)) / 1000 with
#     the servo_steps example, so setup and process start cancel. Mode:
#     host native, valgrind instruction count (deterministic).
# (b) `cargo bench -p hap-core --bench servo_step`: ns per servo step, host
#     native wall clock (depends on the host and its load).
# (c) unless --no-rt: the same cycle in a SCHED_FIFO 80 loop (absolute
#     clock_nanosleep, `chrt -f 80`) for S seconds (default 10) at period P
#     (default 1000 us), with cyclictest -m -p 80 running at the same time
#     (rt-tests). Mode: host native, this machine's (virtualised, non-RT)
#     kernel: a real-kernel comparison, not the target's figures.
# Run it on an otherwise idle host (not next to a QEMU guest).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
rt=1; rt_s=10; period_us=1000; out="$ROOT/build/bench"
while [ $# -gt 0 ]; do
  case "$1" in
    --no-rt) rt=0 ;;
    --rt-seconds) rt_s=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    -h|--help) awk 'NR > 1 && /^#/ { print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    *) echo "bench-step: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done
mkdir -p "$out"
report="$out/step-$(date -u +%Y%m%dT%H%M%SZ).txt"
cd "$ROOT/userspace"
cargo build --release -q -p hap-core --example servo_steps
bin="$ROOT/userspace/target/release/examples/servo_steps"
{
echo "# hapticctrl bench-step on $(uname -r), $(nproc) CPU(s), $(date -u +%FT%TZ)"
echo "## (a) host native, callgrind instruction count"
if command -v valgrind >/dev/null; then
  declare -A ir
  for k in 1000 2000; do
    valgrind --tool=callgrind --callgrind-out-file="$out/callgrind.servo_steps.$k" "$bin" "$k" \
      > /dev/null 2> "$out/callgrind.$k.err"
    ir[$k]=$(sed -n 's/.*Collected : \([0-9]*\).*/\1/p' "$out/callgrind.$k.err")
  done
  echo "Ir(K=1000) = ${ir[1000]}, Ir(K=2000) = ${ir[2000]}"
  echo "instructions per servo cycle [host native, callgrind]: $(( (ir[2000] - ir[1000]) / 1000 ))"
  echo "(callgrind_annotate $out/callgrind.servo_steps.2000 | head -40 for the per-function split)"
else
  echo "valgrind not installed (apt-get install -y valgrind): skipped"
fi
echo "## (b) host native, wall clock: cargo bench -p hap-core --bench servo_step"
cargo bench -q -p hap-core --bench servo_step 2>/dev/null | grep 'ns/step' | sed 's/^/[host native] /'
if [ "$rt" = 1 ]; then
  echo "## (c) host native, SCHED_FIFO 80, ${rt_s} s at ${period_us} us, next to cyclictest"
  if ! command -v cyclictest >/dev/null; then
    echo "cyclictest not installed (apt-get install -y rt-tests): loop alone"
  fi
  if chrt -f 80 true 2>/dev/null; then
    loops=$(( rt_s * 1000000 / period_us ))
    ct_out=$(mktemp)
    if command -v cyclictest >/dev/null; then
      cyclictest -m -p 80 -i "$period_us" -l "$loops" -q > "$ct_out" 2>&1 &
      ctpid=$!
    fi
    chrt -f 80 "$bin" rt "$rt_s" "$period_us" | sed 's/^/[host native SCHED_FIFO] /'
    if [ -n "${ctpid:-}" ]; then
      wait "$ctpid" || true
      grep '^T:' "$ct_out" | sed 's/^/[host native cyclictest] /'
    fi
    rm -f "$ct_out"
  else
    echo "chrt -f 80 not permitted here: skipped"
  fi
fi
} | tee "$report"
echo "bench-step: report $report"
