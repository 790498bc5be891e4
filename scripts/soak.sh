#!/usr/bin/env bash
# Long soak (a separate command, not in CI):
#   scripts/soak.sh [--cycles N] [--period-us P] [--no-load] [--rate HZ]
#                   [--bridge-prio N] [--icount-shift S] [--out DIR]
# One guest (QEMU TCG icount sleep=on: the host<->guest UDP link needs guest
# time to follow real time; with shift S = 2, a guest instruction counts
# 4 ns, so a busy guest's time keeps up with real time here: in-guest times
# are then 4 x the instruction cost of tcg-icount shift 0),
# the controller started by the launch script with the user's effort
# (tests/data/walk.eff), the benchmark load (stress-ng cpu/vm/io/hdd + a
# hackbench loop) in the guest, proto_interface at SCHED_FIFO N (default 50,
# below SERVO's 80; 0: SCHED_OTHER), and the test client (virtuose_demo,
# headless, RATE Hz, default 1000) on the host coupled through it, until the
# module has run N cycles (default 10^6 = 1000 s of guest time at 1 ms:
# 45 min wall here on a shared host with shift 2). Then the client stops, and the module's
# statistics and histograms, the bridge's counters and the client's summary
# are reported.
#
# Asserts correctness only (no kernel warning, no fail-safe, one session,
# N cycles run, the client ran); misses, rates, latencies and loss are
# printed as figures. Output: build/bench/soak-<stamp>/.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
# shellcheck source=scripts/lib.sh
. "$HERE/lib.sh"
ROOT=$HAP_ROOT
cycles=1000000; period_us=1000; load=load; rate=1000; prio=50; shift_s=2; out="$ROOT/build/bench"
while [ $# -gt 0 ]; do
  case "$1" in
    --cycles) cycles=${2:?--cycles needs a number}; shift ;;
    --period-us) period_us=${2:?--period-us needs a number}; shift ;;
    --no-load) load=noload ;;
    --rate) rate=${2:?--rate needs a number}; shift ;;
    --bridge-prio) prio=${2:?--bridge-prio needs a number}; shift ;;
    --icount-shift) shift_s=${2:?--icount-shift needs a number}; shift ;;
    --out) out=${2:?--out needs a directory}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) echo "soak: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
  shift
done
for v in "$cycles" "$period_us" "$rate"; do
  case "$v" in ''|*[!0-9]*|0) echo "soak: '$v' is not a positive integer" >&2; exit 2 ;; esac
done
case "$shift_s" in [0-9]|10) ;; *) echo "soak: --icount-shift wants 0..10, got '$shift_s'" >&2; exit 2 ;; esac
case "$prio" in ''|*[!0-9]*) echo "soak: --bridge-prio wants 0..79, got '$prio'" >&2; exit 2 ;; esac
[ "$prio" -lt 80 ] || { echo "soak: --bridge-prio must stay below SERVO's 80, got $prio" >&2; exit 2; }

bash "$HERE/setup-toolchain.sh" --bench
[ -f "$ROOT/build/base/module/hapticctrl.ko" ] || make -C "$ROOT"
static="$ROOT/userspace/target/x86_64-unknown-linux-gnu/release"
[ -x "$static/proto_interface" ] && [ -x "$static/hapdev" ] || bash "$HERE/build-userspace-static.sh"
demo="$ROOT/userspace/target/release/virtuose_demo"
[ -x "$demo" ] || (cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo)
HAP_EXTRAS=()
[ "$load" = load ] && { hap_add_binaries stress-ng hackbench || log "the load falls back to busybox tools"; }

stamp=$(date -u +%Y%m%dT%H%M%SZ)
dir="$out/soak-$stamp"
mkdir -p "$dir"
qlog="$dir/guest.log"
port=$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
timeout_s=$(( 900 + cycles * period_us / 1000000 * 6 ))
t0=$(date +%s)
key=$(hap_keyfile "$ROOT/build/hap-test.key")
read -r qpid _ < <(HAP_ICOUNT_SHIFT=$shift_s bash "$HERE/qemu-run.sh" --background --icount-sleep --udp "$port:5000" --timeout "$timeout_s" --key "$key" \
  --log "$qlog" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" "${HAP_EXTRAS[@]+"${HAP_EXTRAS[@]}"}" \
  "$ROOT/tests/bench/soak-guest.sh" "$period_us" "$cycles" "$load" "$prio")
cpid=""
cleanup() { [ -n "$cpid" ] && kill "$cpid" 2>/dev/null; kill "$qpid" 2>/dev/null; true; }
trap cleanup EXIT
for _ in $(seq 1800); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; die "the guest did not get ready"; }
log "guest ready; client at $rate Hz on UDP 127.0.0.1:$port until the module has run $cycles cycles (progress: $qlog)"
"$demo" --server "127.0.0.1#$port" --key "$key" --headless --rate "$rate" --timeout-ms 3000 --duration 0 --results "$dir" > "$dir/client.txt" 2>&1 &
cpid=$!
while kill -0 "$qpid" 2>/dev/null && ! grep -q HAP-SOAK-DONE "$qlog"; do
  sleep 5
done
t_done=$(date +%s)
kill -TERM "$cpid" 2>/dev/null || true
crc=0; wait "$cpid" || crc=$?
cpid=""
for _ in $(seq 3000); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
trap - EXIT
kill "$qpid" 2>/dev/null || true
t1=$(date +%s)

between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-" || true; }
between HAP-STATS > "$dir/hap_stats.txt"
between HAP-HIST > "$dir/hap_hist.txt"
between HAP-PROTO > "$dir/proto_interface.txt"
grep '^# soak:' "$qlog" | tr -d '\r' > "$dir/progress.txt" || true
sv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$dir/$1" 2>/dev/null | head -1; }
us() { awk -v n="${1:-0}" 'BEGIN { printf "%.2f", n / 1000 }'; }
mode=$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1)
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
{
  echo "# hapticctrl soak: mode $mode shift=$shift_s (icount sleep=on: while the guest is busy its time is instructions x 2^$shift_s ns)"
  echo "# period $period_us us, $cycles cycles, load: $(sed -n 's/^# load started (\(.*\)): pids.*/\1/p' "$qlog" | tr -d '\r' | head -1 || echo none)"
  echo "# client: virtuose_demo --headless --rate $rate on the host, UDP through proto_interface (SCHED_FIFO $prio; 0 = SCHED_OTHER) in the guest"
  echo "# wall: $((t_done - t0)) s to $cycles cycles, $((t1 - t0)) s in all; guest time $(sed -n 's/.*HAP-SOAK-DONE cycles=[0-9]* guest_ms=\([0-9]*\).*/\1/p' "$qlog" | head -1) ms"
  echo "module: cycles $(sv hap_stats.txt cycles), misses $(sv hap_stats.txt misses), max consecutive $(sv hap_stats.txt max_consecutive_misses), degraded cycles $(sv hap_stats.txt degraded_cycles), fail-safe $(sv hap_stats.txt fail_safe), ticks not posted $(sv hap_stats.txt ticks_not_posted)"
  for s in wakeup exec jitter; do
    echo "module: $s min/avg/max $(us "$(sv hap_stats.txt $s.min_ns)") / $(us "$(sv hap_stats.txt $s.avg_ns)") / $(us "$(sv hap_stats.txt $s.max_ns)") us, p50/p99/p99.9 $(sv hap_stats.txt $s.p50_us) / $(sv hap_stats.txt $s.p99_us) / $(sv hap_stats.txt $s.p99_9_us) us, >=1ms $(sv hap_stats.txt $s.overflow)"
  done
  echo "module: frames in $(sv hap_stats.txt frames_in), rejected $(sv hap_stats.txt frames_rejected), answers sent $(sv hap_stats.txt answers_sent), answers dropped $(sv hap_stats.txt answers_dropped), skipped (latch busy) $(sv hap_stats.txt answers_skipped_latch_busy), VPr extrapolated $(sv hap_stats.txt vpr_extrapolated), sessions opened $(sv hap_stats.txt sessions_opened)"
  echo "bridge: $(tr '\n' ' ' < "$dir/proto_interface.txt" | head -c 600)"
  echo "client: $(grep -E '^(duration_s|vpr_sent|answers|sample_rate_hz|lost|loss_ratio|rtt_ms_mean|rtt_ms_max|coupling_error_mean_m):' "$dir/summary.txt" 2>/dev/null | tr '\n' ' ')"
} > "$dir/report.txt"
cat "$dir/report.txt"
[ "$crc" = 0 ] && ok "the client ran and stopped cleanly" || nok "the client exited $crc: $(tail -3 "$dir/client.txt")"
grep -q HAP-SOAK-DONE "$qlog" && ok "the module ran $cycles cycles" || nok "the guest stopped before $cycles cycles: $(tail -5 "$qlog")"
[ "$(sv hap_stats.txt fail_safe)" = 0 ] && ok "no fail-safe" || nok "fail-safe: $(sv hap_stats.txt fail_safe)"
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed" || nok "guest side: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
echo "soak: $pass passed, $fail failed; report $dir/report.txt, guest log $qlog"
[ "$fail" = 0 ]
