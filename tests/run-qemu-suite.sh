#!/usr/bin/env bash
# Run the QEMU suite: every tests/qemu/NN-*.sh boots its own guest with the
# options on its "# qemu:" line. Prints per-test and total "N passed, N failed",
# and the guest's kernel (`uname -rv`).
#   tests/run-qemu-suite.sh [--debug | --kasan | --stock] [PATTERN]
# --stock boots Debian's stock 7.3 rt-amd64 kernel with the module built
# against its headers (make STOCK=1); the default is the project's test kernel.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
variant_flag=""; pattern=""
for a in "$@"; do
  case "$a" in
    --debug) variant_flag=--debug ;;
    --kasan) variant_flag=--kasan ;;
    --stock) variant_flag=--stock ;;
    *) pattern=$a ;;
  esac
done
total_pass=0; total_fail=0; failed_tests=(); kernel=""
for t in "$ROOT"/tests/qemu/[0-9][0-9]-*.sh; do
  name=$(basename "$t" .sh)
  [ -n "$pattern" ] && [[ "$name" != *$pattern* ]] && continue
  opts=$(sed -n 's/^# qemu: *//p' "$t" | head -1)
  case "$variant_flag" in --debug|--kasan) grep -q '^# qemu-debug: skip' "$t" && continue ;; esac
  echo "=== $name ($opts $variant_flag)"
  out=$(mktemp)
  # shellcheck disable=SC2086
  # The debug kernel (lockdep on every lock operation) is several times
  # slower: its suite runs at a 5 ms period; it checks locking, not timing.
  period=""; case "$variant_flag" in --debug|--kasan) period="--period-us 5000" ;; esac
  bash "$ROOT/scripts/qemu-run.sh" $variant_flag $period $opts "$t" 2>&1 | tee "$out"
  rc=${PIPESTATUS[0]}
  line=$(grep -E '^[0-9]+ passed, [0-9]+ failed' "$out" | tail -1)
  p=$(echo "$line" | awk '{print $1}'); f=$(echo "$line" | awk '{print $3}')
  p=${p:-0}; f=${f:-0}
  if [ "$rc" != 0 ] && [ "$f" = 0 ]; then f=1; fi   # crash, hang or kernel warning
  total_pass=$((total_pass + p)); total_fail=$((total_fail + f))
  [ "$rc" = 0 ] || failed_tests+=("$name")
  k=$(sed -n 's/^HAPTEST-KERNEL //p' "$out" | tr -d '\r' | tail -1); [ -n "$k" ] && kernel=$k
  rm -f "$out"
done
echo "=== QEMU suite${variant_flag:+ (${variant_flag#--} kernel)}: ${#failed_tests[@]} test file(s) failed${failed_tests[*]:+: ${failed_tests[*]}}"
echo "=== guest kernel: ${kernel:-unknown (no guest reported it)}"
echo "qemu: $total_pass passed, $total_fail failed"
[ "$total_fail" = 0 ] && [ ${#failed_tests[@]} = 0 ]
