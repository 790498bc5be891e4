#!/usr/bin/env bash
# Real-time benchmark in ONE guest boot:
#   scripts/bench-rt.sh [--cycles N] [--period-us P] [--long] [--no-cyclictest]
#                       [--busybox-load] [--out DIR]
# Boots tests/bench/rt-guest.sh: N servo cycles idle, then N cycles under a
# heavy userspace load (stress-ng cpu/vm/io/hdd + a hackbench loop; with
# --busybox-load, or if stress-ng is missing: busybox busy loops, dd, a fork
# storm), with cyclictest (rt-tests: same period, SCHED_FIFO 80, 1 us
# histogram) running next to the module in each phase as the anchor.
# Prints a side-by-side table and writes CSVs and histogram plots
# (PNG + SVG, by `hapctl plot`).
#
# Accelerator: qemu-run.sh uses a working KVM where one exists (a
# workstation): the figures are then guest wall-clock latencies. Without
# one (this machine kind: /dev/kvm is PVM, toolchain-notes.md) it runs TCG
# with -icount shift=0,align=off,sleep=off -smp 1: guest time is the
# guest's instruction count (~1 ns per instruction), so the figures are
# deterministic COSTS, not hardware latencies. The report names the mode.
#
# Default N = 10^5 per phase (about 8 min wall here); --long = 10^6 per
# phase (the zero-miss proof; 105 min wall here on a shared host, not for CI).
# Output: build/bench/rt-<stamp>/ (report.txt, guest.log, *.csv, *.png/svg).
# Installs the benchmark tools first (scripts/setup-toolchain.sh --bench).
#
#   scripts/bench-rt.sh --host [--ko FILE] [--cycles N] [--period-us P] ...
# Real hardware: the same phases and report on the RUNNING kernel (a
# PREEMPT_RT machine of your own, e.g. Debian 13 with linux-image-rt-amd64),
# mode "host". It inserts the module into that kernel, so it refuses unless
# --host is given, it runs as root, the running kernel is PREEMPT_RT and is the
# one the module was built for (vermagic = uname -r), the module is not
# loaded, and CI is not set. FILE defaults to build/$(uname -r)/module/
# (make KDIR=/lib/modules/$(uname -r)/build), else the DKMS-installed module.
# The load (stress-ng, hackbench) runs on the machine itself; the bench's
# scratch files live in a private /tmp. Never run it on a build machine.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
# shellcheck source=scripts/lib.sh
. "$HERE/lib.sh"
cycles=100000; period_us=1000; use_ct=1; busybox_load=0; out="$ROOT/build/bench"; host=0; ko=""
while [ $# -gt 0 ]; do
  case "$1" in
    --cycles) cycles=${2:?--cycles needs a number}; shift ;;
    --period-us) period_us=${2:?--period-us needs a number}; shift ;;
    --long) cycles=1000000 ;;
    --no-cyclictest) use_ct=0 ;;
    --busybox-load) busybox_load=1 ;;
    --out) out=${2:?--out needs a directory}; shift ;;
    --host) host=1 ;;
    --ko) ko=${2:?--ko needs a module file}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) echo "bench-rt: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done
case "$cycles" in ''|*[!0-9]*) echo "bench-rt: --cycles wants a positive integer, got '$cycles'" >&2; exit 2 ;; esac
case "$period_us" in ''|*[!0-9]*) echo "bench-rt: --period-us wants an integer, got '$period_us'" >&2; exit 2 ;; esac
[ "$cycles" -ge 1 ] || { echo "bench-rt: --cycles must be >= 1" >&2; exit 2; }
[ -z "$ko" ] || [ "$host" = 1 ] || { echo "bench-rt: --ko is for --host (the QEMU bench uses build/base/)" >&2; exit 2; }

# --host: every refusal comes before anything is installed or loaded.
if [ "$host" = 1 ]; then
  refuse() { echo "bench-rt --host: refusing: $*" >&2; exit 3; }
  krel=$(uname -r)
  [ "${CI:-}" != true ] || refuse "CI=true: the host bench never runs in CI"
  [ "$(id -u)" = 0 ] || refuse "it inserts a kernel module: run as root"
  if [ -z "$ko" ]; then
    for k in "$ROOT/build/$krel/module/hapticctrl.ko" /lib/modules/"$krel"/updates/dkms/hapticctrl.ko*; do
      [ -f "$k" ] && { ko=$k; break; }
    done
  fi
  [ -n "$ko" ] && [ -f "$ko" ] || refuse "no module for $krel (make KDIR=/lib/modules/$krel/build, or install hapticctrl-dkms, or --ko FILE)"
  command -v modinfo >/dev/null || refuse "modinfo (kmod) is missing"
  vermagic=$(modinfo -F vermagic "$ko" 2>/dev/null)
  [ "${vermagic%% *}" = "$krel" ] || refuse "$ko was built for '${vermagic%% *}', the running kernel is '$krel'"
  uname -v | grep -q PREEMPT_RT || refuse "the running kernel ($krel, $(uname -v)) is not PREEMPT_RT"
  ! grep -q '^hapticctrl ' /proc/modules || refuse "hapticctrl is already loaded (hapticctrl.sh stop first)"
fi

bash "$HERE/setup-toolchain.sh" --bench
stamp=$(date -u +%Y%m%dT%H%M%SZ)
dir="$out/rt-$stamp"
mkdir -p "$dir"
log="$dir/guest.log"
report="$dir/report.txt"

HAP_EXTRAS=()
ct_arg=""
if [ "$use_ct" = 1 ]; then
  if hap_add_binaries cyclictest; then ct_arg=cyclictest
  else echo "bench-rt: running without the cyclictest anchor" >&2; fi
fi
if [ "$busybox_load" = 0 ]; then
  hap_add_binaries stress-ng hackbench || echo "bench-rt: the load falls back to busybox tools" >&2
fi

[ "$host" = 1 ] || [ -f "$ROOT/build/base/module/hapticctrl.ko" ] || make -C "$ROOT"
hapctl="$ROOT/userspace/target/release/hapctl"
if [ ! -x "$hapctl" ] && [ "$host" = 1 ] && command -v hapctl >/dev/null; then hapctl=$(command -v hapctl); fi # hapticctrl-tools
[ -x "$hapctl" ] || (cd "$ROOT/userspace" && cargo build --release --quiet -p hapctl)
# Guest time for 2 N cycles plus boot; icount runs well below real time
# under load: allow generously.
# Short periods: the loaded phase's guest time is short, but a busy guest
# runs far below real time (100 us: 20 s of guest time took over 400 s).
timeout_s=$(( 300 + cycles * period_us * 2 / 1000000 * 10 ))
[ "$timeout_s" -ge 2400 ] || timeout_s=2400
t0=$(date +%s)
if [ "$host" = 1 ]; then
  # The guest script on the machine itself, in a private mount namespace
  # with its own /tmp; its console is the log.
  echo "bench-rt --host: $(uname -rv) on $(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1), module $ko" >&2
  {
    echo "HAPTEST-BEGIN $krel hap.mode=host hap.period_us=$period_us"
    echo "HAPTEST-KERNEL $(uname -rv)"
    HAP_KO=$ko HAP_MODE=host HAP_PERIOD_US=$period_us HAP_TESTS_LIB="$ROOT/tests/qemu/lib.sh" \
      timeout "$timeout_s" unshare --mount --propagation private \
      sh -c 'mount -t tmpfs hap-bench /tmp && exec sh "$0" "$@"' "$ROOT/tests/bench/rt-guest.sh" "$cycles" $ct_arg 2>&1
    echo "HAPTEST-RESULT rc=$?"
  } | tee "$log"
  grep -q '^hapticctrl ' /proc/modules && { echo "bench-rt --host: removing the module left loaded" >&2; rmmod hapticctrl || true; }
else
"$HERE/qemu-run.sh" --icount --period-us "$period_us" --timeout "$timeout_s" --log "$log" \
  "${HAP_EXTRAS[@]+"${HAP_EXTRAS[@]}"}" "$ROOT/tests/bench/rt-guest.sh" "$cycles" $ct_arg
fi
t1=$(date +%s)

python3 "$HERE/bench-rt-report.py" "$log" "$dir" "$cycles" "$period_us" "$((t1 - t0))" > "$report"
cat "$report"
# Plots: wake-up latency (SERVO vs cyclictest), execution time, jitter.
plot() { # name title series...
  local name=$1 title=$2; shift 2
  local args=() s
  for s in "$@"; do [ -s "$dir/${s#*=}" ] && args+=("${s%%=*}=$dir/${s#*=}"); done
  [ ${#args[@]} -gt 0 ] || return 0
  "$hapctl" plot hist --log-y --out "$dir/$name" --title "$title" --x-label "µs (1 µs buckets)" \
    --y-label "cycles (log)" "${args[@]}" >/dev/null
}
mode=$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$log" | head -1)
plot latency "Wake-up latency, period $period_us µs, $cycles cycles/phase [$mode]" \
  "SERVO after CLOCK, idle=idle_wakeup.csv" "SERVO after CLOCK, load=load_wakeup.csv" \
  "cyclictest, idle=idle_cyclictest.csv" "cyclictest, load=load_cyclictest.csv"
plot exec "SERVO cycle execution time, period $period_us µs [$mode]" \
  "idle=idle_exec.csv" "load=load_exec.csv"
plot jitter "CLOCK period jitter |dT|, period $period_us µs [$mode]" \
  "idle=idle_jitter.csv" "load=load_jitter.csv"
echo "bench-rt: report $report; plots and CSVs in $dir; guest console $log"
