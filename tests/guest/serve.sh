#!/bin/sh
# In-guest side of the host<->guest link runs (tests/e2e/link.sh and the demo):
# start the controller with the launch script, load the user's effort, serve
# the host's client until it has opened and closed its session (or the time
# limit), then print the module's and the bridge's statistics and the
# simulator log of the whole run (`hapctl log` from the start; gzip, base64)
# between markers, and stop cleanly.
#   serve.sh PERIOD_US MAX_SECONDS
. /tests/lib.sh
period=${1:-2000}
max_s=${2:-120}
check "launch script starts proto_interface and the module" hapticctrl.sh start --period-us "$period"
hapctl log --out /tmp/sim.bin --summary /tmp/simlog.txt 2>/dev/null &
logpid=$!
if [ -f /data/effort.eff ]; then
  check "load the user's effort sequence" dd if=/data/effort.eff of=/dev/hap_effort bs=64k count=1
else
  check "the user grips the handle" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
fi
bp=$(pidof proto_interface)
echo "HAP-BRIDGE-ID uid=$(sed -n 's/^Uid:[[:space:]]*\([0-9]*\).*/\1/p' /proc/$bp/status) gid=$(sed -n 's/^Gid:[[:space:]]*\([0-9]*\).*/\1/p' /proc/$bp/status) capeff=$(sed -n 's/^CapEff:[[:space:]]*//p' /proc/$bp/status)"
echo "HAP-READY period_us=$period"
t=0
while [ $t -lt $((max_s * 10)) ]; do
  opened=$(stat_value sessions_opened); cur=$(stat_value session)
  [ "${opened:-0}" -ge 1 ] && [ "$cur" = 0 ] && break
  # A controller in fail-safe serves no session any more.
  [ "$(stat_value state)" = fail_safe ] && break
  usleep 100000
  t=$((t + 1))
done
expect "a client opened and closed a session" "$(stat_value sessions_opened)" -ge 1
usleep 500000
echo "HAP-STATS-BEGIN"; cat /dev/hap_stats; echo "HAP-STATS-END"
# The bridge's CPU time (all its threads, ns of guest time), for its cost
# per frame.
echo "HAP-BRIDGE-CPU-NS $(cat /proc/$bp/task/*/schedstat 2>/dev/null | awk '{ s += $1 } END { printf "%d", s }')"
kill -USR1 "$(pidof proto_interface)" 2>/dev/null; usleep 300000
echo "HAP-PROTO-BEGIN"; cat /run/proto_interface.stats 2>/dev/null; echo "HAP-PROTO-END"
# The guest's UDP counters (the bridge's socket is the only one): datagrams
# delivered to it and dropped for a full receive buffer.
echo "HAP-UDP $(awk '/^Udp:/ { if (!h) { split($0, k); h = 1 } else { for (i = 2; i <= NF; i++) printf "%s=%s ", k[i], $i } }' /proc/net/snmp)"
# The stop request runs the fail-safe, which closes the position log: the
# recorder drains it and exits.
echo 1 > /dev/hap_stop
wait "$logpid"
expect "the position log recorder ended cleanly" "$?" = 0
echo "HAP-SIMLOG-SUMMARY-BEGIN"; cat /tmp/simlog.txt; echo "HAP-SIMLOG-SUMMARY-END"
echo "HAP-HIST-BEGIN"; cat /dev/hap_hist; echo "HAP-HIST-END"
# Kernel messages on the console would cut into the base64 lines (the host
# also strips "[ time] message" tails).
lvl=$(cut -f1 /proc/sys/kernel/printk 2>/dev/null)
dmesg -n 1 2>/dev/null
echo "HAP-SIMLOG-BEGIN"; gzip -1 -c /tmp/sim.bin | base64; echo "HAP-SIMLOG-END"
[ -n "$lvl" ] && dmesg -n "$lvl" 2>/dev/null
check "launch script stops cleanly" hapticctrl.sh stop
check_not "the module is unloaded" sh -c 'grep -q ^hapticctrl /proc/modules'
finish
