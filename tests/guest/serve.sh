#!/bin/sh
# In-guest side of the host<->guest link runs (tests/e2e/link.sh and the demo):
# start the controller with the launch script, load the user's effort, serve
# the host's client until it has opened and closed its session (or the time
# limit), then print the module's and the bridge's statistics and the
# simulator log (base64) between markers, and stop cleanly.
#   serve.sh PERIOD_US MAX_SECONDS
. /tests/lib.sh
period=${1:-2000}
max_s=${2:-120}
check "launch script starts proto_interface and the module" hapticctrl.sh start --period-us "$period"
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
  usleep 100000
  t=$((t + 1))
done
expect "a client opened and closed a session" "$(stat_value sessions_opened)" -ge 1
usleep 500000
echo "HAP-STATS-BEGIN"; cat /dev/hap_stats; echo "HAP-STATS-END"
kill -USR1 "$(pidof proto_interface)" 2>/dev/null; usleep 300000
echo "HAP-PROTO-BEGIN"; cat /run/proto_interface.stats 2>/dev/null; echo "HAP-PROTO-END"
hapdev simlog --raw /tmp/sim.bin > /dev/null
echo "HAP-SIMLOG-BEGIN"; base64 /tmp/sim.bin; echo "HAP-SIMLOG-END"
check "launch script stops cleanly" hapticctrl.sh stop
check_not "the module is unloaded" sh -c 'grep -q ^hapticctrl /proc/modules'
finish
