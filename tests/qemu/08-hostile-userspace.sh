#!/bin/sh
# qemu: --icount --period-us 250 --timeout 1500
# qemu-debug: skip (3*10^4 cycles at 250 us: a timing test, not a locking one; lockdep runs the other tests at 5 ms)
# Nothing outside the cycle can stall it. At 250 us, with a client session
# coupled over rtf_in/rtf_out: a quiet phase, then a hostile one of >= 3*10^4
# cycles (the suite's; the first argument sets it: the full campaign is
#   scripts/qemu-run.sh --stock --icount --period-us 250 --timeout 3000 \
#     tests/qemu/08-hostile-userspace.sh 100000
# ; the load checks' fixed floors assume >= 3*10^4) where userspace does
# its worst with every device: /dev/hap_stats,
# /dev/hap_hist and /dev/hap_power read in tight loops, a 64 KiB effort
# sequence written to /dev/hap_effort every 10 ms, and the session's own
# reader (the rtf_out reader) stopped with SIGSTOP for 1 s mid-session. A
# reader that is never stopped drains /dev/hap_simlog all along. Asserts:
# no deadline miss, a complete position log (every cycle's record, none
# refused), no answer skipped because of monitoring (SERVO reads the VPr
# latch, which only PROTO_IN publishes: while the client is stopped no
# answer is skipped), and that
# the load really ran. Prints the SERVO wake-up figures of both phases.
. /tests/lib.sh
QUIET=${HAP_QUIET_CYCLES:-20000}
N=${1:-${HAP_HOSTILE_CYCLES:-30000}}
echo "# mode: $HAP_MODE, period $HAP_PERIOD_US us, quiet $QUIET cycles, hostile $N cycles"

# A 64 KiB effort sequence: 100 keyframes (the player holds 128), padded
# with comment lines to 65536 bytes exactly.
awk 'BEGIN {
  out = "";
  for (i = 0; i < 100; i++) out = out sprintf("%d 0.%d 0 0 0 0 0 1\n", i * 20, i % 10);
  pad = "# padding ................................................................................................\n";
  while (length(out) + length(pad) <= 65536 - 2) out = out pad;
  while (length(out) < 65535) out = out "#";
  printf "%s\n", out;
}' > /tmp/big.eff
expect "the effort sequence is 64 KiB" "$(wc -c < /tmp/big.eff)" = 65536

figures() { # PHASE FILE: the SERVO wake-up figures of a stats snapshot
  echo "# figures $1 [$HAP_MODE, $HAP_PERIOD_US us]: $(grep -E '^(cycles|misses|wakeup\.(min_ns|avg_ns|p50_us|p99_us|p99_9_us|max_ns)|exec\.(avg_ns|max_ns)|answers_(sent|skipped_lock_busy)|vpr_extrapolated|stats_read_busy):' "$2" | tr '\n' ' ')"
}
wait_cycles() { # wait until the cycle counter reaches $1
  c=$(stat_value cycles)
  while [ "${c:-0}" -lt "$1" ]; do
    sleep 1
    c=$(stat_value cycles)
  done
}

check "insmod period_us=$HAP_PERIOD_US" insmod $HAP_KO period_us=$HAP_PERIOD_US
# The drain: one blocking reader of the position log for the whole run.
cat /dev/hap_simlog > /tmp/simlog.bin &
DRAIN=$!
check "the user grips the handle (live effort, dead-man on)" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
total_ms=$(( (QUIET + N) * HAP_PERIOD_US / 1000 + 4000 ))
hapdev couple --offset 0.03,0,0.02 --ms "$total_ms" > /tmp/couple.txt 2>&1 &
COUPLE=$!

echo "# --- quiet phase: the session and the drain only"
sleep 1
c0=$(stat_value cycles)
wait_cycles $((c0 + QUIET))
cat /dev/hap_stats > /tmp/stats.quiet
figures quiet /tmp/stats.quiet
q_skipped=$(sed -n 's/^answers_skipped_latch_busy: //p' /tmp/stats.quiet)

echo "# --- hostile phase"
PIDS=""
for d in hap_stats hap_hist hap_power; do
  sh -c "n=0; while :; do cat /dev/$d > /dev/null && n=\$((n + 1)) && echo \$n > /tmp/reads.$d; done" &
  PIDS="$PIDS $!"
done
sh -c 'n=0; while :; do
  if dd if=/tmp/big.eff of=/dev/hap_effort bs=64k count=1 2>/dev/null; then n=$((n + 1)); echo $n > /tmp/effort.ok; fi
  usleep 10000
done' &
PIDS="$PIDS $!"
h0=$(stat_value cycles)
m0=$(stat_value misses)
s0=$(stat_value answers_skipped_latch_busy)
a0=$(stat_value answers_sent)
wait_cycles $((h0 + N / 3))
# Stop the session's reader (it reads rtf_out) in the middle of the session.
# While it is stopped the client sends nothing, so PROTO_IN (the only
# publisher of the VPr latch) goes idle once it drained rtf_in: an answer
# skipped in that window could only come from the monitoring loops.
kill -STOP $COUPLE
echo "# session reader stopped at cycle $(stat_value cycles)"
sleep_cycles 200
w0=$(stat_value answers_skipped_latch_busy)
sleep 1
w1=$(stat_value answers_skipped_latch_busy)
kill -CONT $COUPLE
echo "# session reader continued at cycle $(stat_value cycles)"
wait_cycles $((h0 + N))
cat /dev/hap_stats > /tmp/stats.hostile
# shellcheck disable=SC2086
kill $PIDS 2>/dev/null
wait $COUPLE
couple_rc=$?
figures hostile /tmp/stats.hostile
v() { sed -n "s/^$1: *\([^ ]*\).*/\1/p" /tmp/stats.hostile; }
h1=$(v cycles)

expect "hostile phase: >= $N cycles" $((h1 - h0)) -ge "$N"
expect "no deadline miss in the whole run" "$(v misses)" = 0
expect "no deadline miss in the hostile phase" $(( $(v misses) - m0 )) = 0
expect "state is running" "$(v state)" = running
expect "no answer skipped while only monitoring ran (1 s, client stopped)" $((w1 - w0)) = 0
echo "# answers skipped (the VPr latch read overlapped PROTO_IN publishing): quiet phase $q_skipped, hostile phase $(( $(v answers_skipped_latch_busy) - s0 ))"
expect "answers kept flowing in the hostile phase" $(( $(v answers_sent) - a0 )) -ge $(( N / 2 ))
expect "the 64 KiB effort loads went through (>= 100)" "$(cat /tmp/effort.ok 2>/dev/null || echo 0)" -ge 100
check "dmesg: effort sequences loaded" dmesg_has 'effort sequence loaded: 100 keyframes'
for d in hap_stats hap_hist hap_power; do
  expect "/dev/$d was read in a tight loop (>= 100 reads)" "$(cat /tmp/reads.$d 2>/dev/null || echo 0)" -ge 100
done
expect "the position log refused no record" "$(v simlog.dropped)" = 0
sed 's/^/# couple /' /tmp/couple.txt
expect "the session ran to its end" "$couple_rc" = 0

# The drain got every record: consecutive cycles from the first on. Let it
# catch up, then stop it (an open file keeps the module loaded).
pushed=$(v simlog.pushed)
sleep 1
expect "the position log refused no record, drain caught up" "$(stat_value simlog.dropped)" = 0
kill $DRAIN
wait $DRAIN 2>/dev/null
check "rmmod" rmmod hapticctrl
hapdev simlog --dev /tmp/simlog.bin > /tmp/simlog.txt
sed 's/^/# simlog /' /tmp/simlog.txt
records=$(sed -n 's/^records: //p' /tmp/simlog.txt)
first=$(sed -n 's/^first_cycle: //p' /tmp/simlog.txt)
last=$(sed -n 's/^last_cycle: //p' /tmp/simlog.txt)
expect "the drain starts at the first record" "$first" -le 1
expect "the drain holds every cycle from the first to the last (no gap)" "$records" = $((last - first + 1))
expect "the drain holds at least every record pushed before the hostile snapshot" "$records" -ge "$pushed"
finish
