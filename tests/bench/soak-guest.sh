#!/bin/sh
# In-guest side of scripts/soak.sh (not part of the test suite): the
# controller started by the launch script, the user's effort loaded, the
# benchmark load running (stress-ng + hackbench, tests/qemu/lib.sh), and the
# host's test client coupled through proto_interface, until the module has
# run CYCLES cycles. Progress every 10 s of guest time; then the module's
# statistics and histograms, the bridge's counters, between markers.
#   soak-guest.sh PERIOD_US CYCLES [load|noload] [BRIDGE_FIFO_PRIORITY (0: SCHED_OTHER)]
. /tests/lib.sh
period=${1:-1000}
N=${2:-1000000}
LOAD=${3:-load}
PRIO=${4:-0}
[ "$PRIO" != 0 ] && export HAP_PROTO_ARGS="--rt-priority $PRIO"
check "launch script starts proto_interface and the module" hapticctrl.sh start --period-us "$period"
if [ -f /data/effort.eff ]; then
  check "load the user's effort sequence" dd if=/data/effort.eff of=/dev/hap_effort bs=64k count=1
fi
[ "$LOAD" = load ] && start_load
echo "HAP-READY period_us=$period"
t0=$(now_ms)
c=$(stat_value cycles)
while [ "${c:-0}" -lt "$N" ]; do
  sleep 10
  c=$(stat_value cycles)
  echo "# soak: t=$(( ($(now_ms) - t0) / 1000 ))s cycles=$c misses=$(stat_value misses) max_consec=$(stat_value max_consecutive_misses) fail_safe=$(stat_value fail_safe) session=$(stat_value session) frames_in=$(stat_value frames_in) answers=$(stat_value answers_sent)"
  [ "$(stat_value fail_safe)" = 0 ] || break
done
echo "HAP-SOAK-DONE cycles=$c guest_ms=$(( $(now_ms) - t0 ))"
# The host stops its client now: wait until it has closed its session.
t=0
while [ $t -lt 600 ]; do
  [ "$(stat_value sessions_opened)" -ge 1 ] && [ "$(stat_value session)" = 0 ] && break
  usleep 100000
  t=$((t + 1))
done
cat /dev/hap_stats > /tmp/stats.soak
cat /dev/hap_hist > /tmp/hist.soak
[ "$LOAD" = load ] && stop_load
expect "the module ran the requested cycles" "$(sed -n 's/^cycles: //p' /tmp/stats.soak)" -ge "$N"
expect "no fail-safe during the soak" "$(sed -n 's/^fail_safe: //p' /tmp/stats.soak)" = 0
expect "the client opened exactly one session" "$(sed -n 's/^sessions_opened: //p' /tmp/stats.soak)" = 1
echo "HAP-STATS-BEGIN"; cat /tmp/stats.soak; echo "HAP-STATS-END"
echo "HAP-HIST-BEGIN"; grep -v '^#' /tmp/hist.soak; echo "HAP-HIST-END"
kill -USR1 "$(pidof proto_interface)" 2>/dev/null; usleep 300000
echo "HAP-PROTO-BEGIN"; cat /run/proto_interface.stats 2>/dev/null; echo "HAP-PROTO-END"
check "launch script stops cleanly" hapticctrl.sh stop
check_not "the module is unloaded" sh -c 'grep -q ^hapticctrl /proc/modules'
finish
