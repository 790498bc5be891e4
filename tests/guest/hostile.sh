#!/bin/sh
# In-guest side of the hostile-input campaign (scripts/bench-hostile.sh):
# start the controller with the launch script, load the user's effort, wait
# for the host's legitimate client to open its session, then write DEV_COUNT
# hostile frames straight into /dev/hap_rtf_in next to that session (what a
# broken or compromised bridge could write: wrong session, replayed sequence
# numbers, NaN/Inf, bad CRC, bad lengths... built by hapdev with hap-core),
# while the host sends its hostile datagrams at the bridge. Serve until the
# client closes its session (or the time limit), then print the module's and
# the bridge's statistics between markers, and stop cleanly.
#   hostile.sh PERIOD_US MAX_SECONDS DEV_COUNT DEV_INTERVAL_US
. /tests/lib.sh
period=${1:-1000}
max_s=${2:-300}
dev_count=${3:-20000}
dev_iv=${4:-2000}
check "launch script starts proto_interface and the module" hapticctrl.sh start --period-us "$period"
if [ -f /data/effort.eff ]; then
  check "load the user's effort sequence" dd if=/data/effort.eff of=/dev/hap_effort bs=64k count=1
else
  check "the user grips the handle" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
fi
echo "HAP-READY period_us=$period"
t=0
while [ $t -lt $((max_s * 10)) ]; do
  [ "$(stat_value session)" != 0 ] && break
  usleep 100000
  t=$((t + 1))
done
session=$(stat_value session)
expect "the host's client opened a session" "$session" -ge 1
usleep 2000000   # the client's sequence numbers are well past the replayed ones
echo "HAP-STATS0-BEGIN"; cat /dev/hap_stats; echo "HAP-STATS0-END"
if [ "$dev_count" -gt 0 ]; then
  hapdev hostile dev --session "$session" --count "$dev_count" --interval-us "$dev_iv" > /tmp/hostile_dev.txt 2>&1
  echo "hostile dev rc=$?"
  echo "HAP-HOSTILE-DEV-BEGIN"; cat /tmp/hostile_dev.txt; echo "HAP-HOSTILE-DEV-END"
fi
expect "the session survived the device-level campaign" "$(stat_value session)" = "$session"
# Until the client closes its session, or the bridge no longer has a client
# (closed or expired: then the module's session was left open).
while [ $t -lt $((max_s * 10)) ]; do
  opened=$(stat_value sessions_opened); cur=$(stat_value session)
  [ "${opened:-0}" -ge 1 ] && [ "$cur" = 0 ] && break
  grep -q '^client: none' /run/proto_interface.stats 2>/dev/null && break
  usleep 100000
  t=$((t + 1))
done
expect "the client closed its session" "$(stat_value session)" = 0
usleep 500000
echo "HAP-STATS-BEGIN"; cat /dev/hap_stats; echo "HAP-STATS-END"
echo "HAP-UDP-BEGIN"; grep '^Udp:' /proc/net/snmp; echo "HAP-UDP-END"
kill -USR1 "$(pidof proto_interface)" 2>/dev/null; usleep 300000
echo "HAP-PROTO-BEGIN"; cat /run/proto_interface.stats 2>/dev/null; echo "HAP-PROTO-END"
check "launch script stops cleanly" hapticctrl.sh stop
check_not "the module is unloaded" sh -c 'grep -q ^hapticctrl /proc/modules'
finish
