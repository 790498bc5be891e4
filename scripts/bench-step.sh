#!/usr/bin/env bash
# Host-side, repeatable cost of one SERVO cycle:
#   scripts/bench-step.sh [--no-rt] [--rt-seconds S] [--period-us P] [--load]
# (a) callgrind: instructions per full cycle (hap_core::cycle::ServoCycle +
#     answer encoding + log record), = (Ir(K=2000) - Ir(K=1000)) / 1000 with
#     the servo_steps example, so setup and process start cancel; the
#     controller alone (the full cycle less the simulated arm:
#     Simulator::measures and Simulator::simulate_arm, their kinematics
#     included); and the per-function split (inclusive Ir per cycle of the
#     calls into each function). At a servo period of 1 ms (the module's
#     default) and of 100 us (its floor): the simulated arm integrates in
#     sub-steps of at most 500 us, 2 at 1 ms, 1 at 100 us. Mode: host
#     native, valgrind instruction count (deterministic). Then, at 1 ms,
#     per arm with two arms (arms=2: SERVO steps both in one cycle): arm 0's
#     cycle, and what arm 1 adds, = (Ir(K=2000) - Ir(K=1000)) / 1000 with
#     two arms less the one-arm figure; each is checked against the
#     project's budget of 15 000 instructions per arm and cycle.
# (b) `cargo bench -p hap-core --bench servo_step`: ns per servo step, host
#     native wall clock (depends on the host and its load).
# (c) unless --no-rt: the same cycle in a SCHED_FIFO 80 loop (absolute
#     clock_nanosleep, `chrt -f 80`) for S seconds (default 10) at period P
#     (default 1000 us), with cyclictest -m -p 80 running at the same time
#     (rt-tests). Mode: host native, this machine's (virtualised, non-RT)
#     kernel: a real-kernel comparison, not the target's figures. With
#     --load, stress-ng (cpu, vm, io, hdd) and a hackbench loop run on the
#     host meanwhile. Histograms of both go to CSV and a plot (hapctl plot).
# --link: the VPr is a link-passive client's (CTRL_LINK_ENERGY, about 1 W of
#   energy grants): the cost of the link passivity path (control.md).
# Run it on an otherwise idle host (not next to a QEMU guest).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
rt=1; rt_s=10; period_us=1000; load=0; out="$ROOT/build/bench"
while [ $# -gt 0 ]; do
  case "$1" in
    --no-rt) rt=0 ;;
    --rt-seconds) rt_s=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    --load) load=1 ;;
    --link) export HAP_STEP_LINK=1 ;;
    -h|--help) awk 'NR > 1 && /^#/ { print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    *) echo "bench-step: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done
for v in "$rt_s" "$period_us"; do
  case "$v" in ''|*[!0-9]*|0) echo "bench-step: '$v' is not a positive integer" >&2; exit 2 ;; esac
done
bash "$HERE/setup-toolchain.sh" --bench
# Sum of the inclusive Ir of the calls into the functions whose name matches
# the regular expression $2, from callers that do not match it (nested calls
# are not counted twice), in the callgrind output file $1. Functions that the
# compiler inlined have no calls of their own: count them through a caller.
callgrind_calls() {
  python3 - "$1" "$2" <<'PY'
import re, sys
path, pat = sys.argv[1], re.compile(sys.argv[2])
names = {}
def name(spec):
    m = re.match(r'\((\d+)\)(?: (.*))?', spec)
    if not m:
        return spec
    if m.group(2) is not None:
        names[m.group(1)] = m.group(2)
    return names.get(m.group(1), '')
fn = cfn = ''
total = 0
pending = False
for line in open(path):
    if line.startswith('fn='):
        fn = name(line[3:].strip())
    elif line.startswith('cfn='):
        cfn = name(line[4:].strip())
    elif line.startswith('calls='):
        pending = True
    elif pending:
        pending = False
        if pat.search(cfn) and not pat.search(fn):
            total += int(line.split()[1])
print(total)
PY
}
stamp=$(date -u +%Y%m%dT%H%M%SZ)
mkdir -p "$out/step-$stamp"
report="$out/step-$stamp/report.txt"
cd "$ROOT/userspace"
cargo build --release -q -p hap-core --example servo_steps
cargo build --release -q -p hapctl
bin="$ROOT/userspace/target/release/examples/servo_steps"
{
echo "# hapticctrl bench-step on $(uname -r), $(nproc) CPU(s), $(date -u +%FT%TZ)"
echo "## (a) host native, callgrind instruction count"
if command -v valgrind >/dev/null; then
  for cg_period in 1000 100; do
  echo "### servo period ${cg_period} us"
  declare -A ir
  for k in 1000 2000; do
    valgrind --tool=callgrind --callgrind-out-file="$out/step-$stamp/callgrind.servo_steps.$cg_period.$k" "$bin" "$k" "$cg_period" \
      > /dev/null 2> "$out/step-$stamp/callgrind.$cg_period.$k.err"
    ir[$k]=$(sed -n 's/.*Collected : \([0-9]*\).*/\1/p' "$out/step-$stamp/callgrind.$cg_period.$k.err")
  done
  echo "Ir(K=1000) = ${ir[1000]}, Ir(K=2000) = ${ir[2000]}"
  full=$(( (ir[2000] - ir[1000]) / 1000 ))
  echo "instructions per servo cycle at ${cg_period} us [host native, callgrind]: $full"
  # Inclusive Ir per cycle of the calls into the functions matching $1.
  per_cycle() {
    local a b
    a=$(callgrind_calls "$out/step-$stamp/callgrind.servo_steps.$cg_period.1000" "$1")
    b=$(callgrind_calls "$out/step-$stamp/callgrind.servo_steps.$cg_period.2000" "$1")
    echo $(( (b - a) / 1000 ))
  }
  sim=$(per_cycle 'hap_core::simulator::Simulator::(measures|simulate_arm)$')
  echo "instructions per cycle at ${cg_period} us, controller alone (full cycle less the simulated arm) [host native, callgrind]: $(( full - sim ))"
  echo "instructions per cycle at ${cg_period} us, simulated arm (measures + simulate_arm) [host native, callgrind]: $sim"
  echo "per-function split at ${cg_period} us, inclusive instructions per cycle [host native, callgrind]:"
  for f in 'hap_core::servo::Servo::step$' 'hap_core::simulator::Simulator::measures$' \
           'hap_core::simulator::Simulator::simulate_arm$' 'hap_core::arm::kinematics' \
           'hap_core::state_model::build_physical_state$' 'hap_core::control::cartesian_control$' \
           'hap_core::control::spring_energy$' 'hap_core::arm::Kinematics::jacobian_transpose_mul$' \
           'hap_core::fixed::Fx::sin_cos_unit$' 'hap_core::fixed::Quat::from_mat3$' \
           'hap_core::proto_synchro::Synchro::receive_vp$' 'hap_core::protocol::encode$' \
           'hap_core::position_log::LogRecord::encode$'; do
    printf '  %-50s %6d\n' "$(echo "$f" | sed 's/^hap_core:://; s/\$$//')" "$(per_cycle "$f")"
  done
  echo "(callgrind_annotate $out/step-$stamp/callgrind.servo_steps.$cg_period.2000 | head -40 for the self cost)"
  [ "$cg_period" = 1000 ] && one_arm=$full
  done
  echo "### two arms (arms=2) at 1000 us"
  declare -A ir2
  for k in 1000 2000; do
    valgrind --tool=callgrind --callgrind-out-file="$out/step-$stamp/callgrind.servo_steps.arms2.$k" "$bin" "$k" 1000 2 \
      > /dev/null 2> "$out/step-$stamp/callgrind.arms2.$k.err"
    ir2[$k]=$(sed -n 's/.*Collected : \([0-9]*\).*/\1/p' "$out/step-$stamp/callgrind.arms2.$k.err")
  done
  both=$(( (ir2[2000] - ir2[1000]) / 1000 ))
  echo "instructions per servo cycle at 1000 us, both arms [host native, callgrind]: $both"
  for a in 0 1; do
    if [ "$a" = 0 ]; then n=$one_arm; else n=$(( both - one_arm )); fi
    verdict=$([ "$n" -le 15000 ] && echo "within" || echo "OVER")
    echo "instructions per cycle per arm at 1000 us, arm $a [host native, callgrind]: $n ($verdict the 15 000 budget)"
  done
else
  echo "valgrind not installed (apt-get install -y valgrind): skipped"
fi
echo "## (b) host native, wall clock: cargo bench -p hap-core --bench servo_step"
cargo bench -q -p hap-core --bench servo_step 2>/dev/null | grep 'ns/step' | sed 's/^/[host native] /'
if [ "$rt" = 1 ]; then
  echo "## (c) host native, SCHED_FIFO 80, ${rt_s} s at ${period_us} us, next to cyclictest$([ "$load" = 1 ] && echo ", host loaded: stress-ng --cpu 2 --vm 1 --vm-bytes 256M --io 1 --hdd 1 + hackbench loop")"
  if ! command -v cyclictest >/dev/null; then
    echo "cyclictest not installed (apt-get install -y rt-tests): loop alone"
  fi
  if chrt -f 80 true 2>/dev/null; then
    loops=$(( rt_s * 1000000 / period_us ))
    ct_out=$(mktemp)
    lpids=""
    if [ "$load" = 1 ]; then
      # Own session: stress-ng signals its process group when it ends.
      setsid stress-ng --cpu 2 --vm 1 --vm-bytes 256M --io 1 --hdd 1 --hdd-bytes 64M --temp-path /tmp \
        --timeout $((rt_s + 5)) > /dev/null 2>&1 & lpids="$!"
      (end=$(( $(date +%s) + rt_s + 5 )); while [ "$(date +%s)" -lt "$end" ]; do hackbench -g 4 -l 200 -s 100 > /dev/null 2>&1 || break; done) &
      lpids="$lpids $!"
      sleep 1
    fi
    hdir="$out/step-$stamp"
    if command -v cyclictest >/dev/null; then
      cyclictest -m -p 80 -i "$period_us" -l "$loops" -q -h 20000 --histfile="$hdir/cyclictest.hist" > "$ct_out" 2>&1 &
      ctpid=$!
    fi
    chrt -f 80 "$bin" rt "$rt_s" "$period_us" "$hdir" | sed 's/^/[host native SCHED_FIFO] /'
    if [ -n "${ctpid:-}" ]; then
      wait "$ctpid" || true
      sed -n 's/^# \(Min\|Avg\|Max\) Latencies: 0*\([0-9]\)/\1 \2/p' "$hdir/cyclictest.hist" | tr '\n' ' ' |
        sed 's/^/[host native cyclictest] latency us: /'; echo
      awk 'BEGIN { print "us,count" } !/^#/ && $2 + 0 > 0 { print $1 + 0 "," $2 + 0 }' "$hdir/cyclictest.hist" > "$hdir/cyclictest.csv"
    fi
    # shellcheck disable=SC2086
    [ -n "$lpids" ] && { kill $lpids 2>/dev/null; wait $lpids 2>/dev/null; true; }
    rm -f "$ct_out"
    "$ROOT/userspace/target/release/hapctl" plot hist --log-y --out "$hdir/host_latency" \
      --title "Host native, SCHED_FIFO 80, $period_us µs$([ "$load" = 1 ] && echo ", loaded")" \
      --x-label "µs (1 µs buckets)" --y-label "cycles (log)" \
      "servo loop wake-up=$hdir/host_loop_wakeup.csv" "servo loop cycle time=$hdir/host_loop_cycle.csv" \
      $([ -s "$hdir/cyclictest.csv" ] && echo "cyclictest=$hdir/cyclictest.csv") > /dev/null &&
      echo "plot: $hdir/host_latency.png / .svg"
  else
    echo "chrt -f 80 not permitted here: skipped"
  fi
fi
} | tee "$report"
echo "bench-step: report $report"
