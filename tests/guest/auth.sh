#!/bin/sh
# In-guest side of tests/e2e/auth.sh: the controller started by the launch
# script with the key, the user gripping the handle without effort, the arm
# powered. While the host's keyless clients attack, the position log is
# recorded; once the bridge has counted the host's end-of-attack marker
# (oversized datagrams) and 1.5 s passed without a new refusal (and nothing
# was verified yet), the recording stops and the
# handle's largest displacement is printed (HAP-ATTACK-DONE). Then serve the
# host's key-holding client until it has opened and closed its session, and
# print the module's and the bridge's statistics between markers.
#   auth.sh PERIOD_US MAX_SECONDS [FAIR_SERVER_RUNTIME_NS|default [RT_BUDGET]]
# For diagnosis: the third argument sets the runtime of the kernel's fair
# server (its protection of SCHED_OTHER tasks against real-time tasks that
# hold the CPU; by default 50 ms per second) through debugfs, the fourth the
# bridge's --rt-budget (default 25; 100: never leaves SCHED_FIFO).
. /tests/lib.sh
period=${1:-1000}
max_s=${2:-240}
fair_ns=${3:-default}
rt_budget=${4:-25}
if [ "$fair_ns" != default ]; then
  mount -t debugfs none /sys/kernel/debug 2>/dev/null
  echo "$fair_ns" > /sys/kernel/debug/sched/fair_server/cpu0/runtime
  echo "HAP-FAIR-SERVER runtime_ns=$(cat /sys/kernel/debug/sched/fair_server/cpu0/runtime)"
fi
# The bridge at a real-time priority: it then keeps CAP_SYS_NICE, and only it.
check "launch script starts proto_interface and the module" env HAP_PROTO_ARGS="--rt-priority 50 --rt-budget $rt_budget" hapticctrl.sh start --period-us "$period"
check "the user grips the handle, no effort" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
check "arm powered" hapctl power on
bp=$(pidof proto_interface)
echo "HAP-BRIDGE-ID uid=$(sed -n 's/^Uid:[[:space:]]*\([0-9]*\).*/\1/p' /proc/$bp/status) gid=$(sed -n 's/^Gid:[[:space:]]*\([0-9]*\).*/\1/p' /proc/$bp/status) capeff=$(sed -n 's/^CapEff:[[:space:]]*//p' /proc/$bp/status)"
echo "HAP-RUNDIR $(ls -lnd /run /run/hapticctrl | tr '\n' ' ') $(ls -ln /run | tr '\n' ' ')"
echo "HAP-DEVICES $(ls -ln /dev/hap_rtf_in /dev/hap_rtf_out | awk '{ printf "%s:%s:%s ", $1, $3, $4 }')"
usleep 500000
hapctl log > /tmp/attack.csv &
logger=$!
echo "HAP-READY period_us=$period"
pv() { kill -USR1 "$bp" 2>/dev/null; usleep 50000; sed -n "s/^$1: *//p" /run/proto_interface.stats 2>/dev/null | head -1; }
last=0; quiet=0; t=0
while [ $t -lt $((max_s * 10)) ]; do
  usleep 100000
  t=$((t + 1))
  kill -0 "$bp" 2>/dev/null || { fail "the bridge is gone ($(tail -3 /run/proto_interface.log | tr '\n' ' '); $(grep -E '^(state|fail_safe):' /dev/hap_stats | tr '\n' ' '))"; break; }
  r=$(pv rejected); v=$(pv verified)
  if [ -z "$r" ]; then
    missing=$((${missing:-0} + 1))
    [ "$missing" -ge 20 ] && { fail "no bridge counters ($(ls -ln /run/hapticctrl 2>&1 | tr '\n' ' '); $(grep -v '^[a-z_]*: ' /run/proto_interface.log | tail -6 | tr '\n' ' '))"; break; }
  fi
  [ "${v:-0}" -gt 0 ] && break
  if [ "${r:-0}" -gt 0 ] && [ "$r" = "$last" ]; then quiet=$((quiet + 1)); else quiet=0; fi
  last=$r
  # The host ends the attacks with oversized datagrams (no attacker sends
  # any): once they were counted, 1.5 s without a new refusal end the phase.
  [ $quiet -ge 15 ] && [ "$(pv rejected_oversize)" -gt 0 ] && break
done
kill "$logger"; wait "$logger" 2>/dev/null
expect "nothing was verified during the attack" "$(pv verified)" -eq 0
echo "HAP-ATTACK-STATS-BEGIN"; cat /run/proto_interface.stats; grep -E '^(sessions_opened|frames_in|vpr_frames|session|power|cycles):' /dev/hap_stats; echo "HAP-ATTACK-STATS-END"
# Largest displacement of the handle over the recorded cycles, squared (m^2:
# busybox awk may lack sqrt; the host takes the root).
# The columns are found by name in the CSV header (hapctl's simlog format).
awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; if (!c["hx"]) exit; next }
  { x = $(c["hx"]); y = $(c["hy"]); z = $(c["hz"]) }
  NR == 2 { x0 = x; y0 = y; z0 = z }
  { d = (x - x0) * (x - x0) + (y - y0) * (y - y0) + (z - z0) * (z - z0); if (d > m) m = d; n++ }
  { f = $(c["coupling_fx"]) * $(c["coupling_fx"]) + $(c["coupling_fy"]) * $(c["coupling_fy"]) + $(c["coupling_fz"]) * $(c["coupling_fz"]); if (f > cf) cf = f }
  { if (int($(c["status"]) / 128) % 2) coupled++ }
  END { printf "HAP-ATTACK-DONE records=%d max_displacement_m2=%.15f max_coupling_n2=%.15f coupled=%d\n", n, m, cf, coupled + 0 }' /tmp/attack.csv
# CPU accounting of the key holder's phase: the bridge's threads (ns on the
# CPU, /proc/PID/task/*/schedstat) and the CPU's split (/proc/stat, ticks).
bridge_ns() { cat /proc/$bp/task/*/schedstat 2>/dev/null | awk '{ s += $1 } END { printf "%.0f", s }'; }
cpu_line() { sed -n 's/^cpu  *//p' /proc/stat; }
b0=$(bridge_ns); c0=$(cpu_line); up0=$(cut -d' ' -f1 /proc/uptime)
t=0
while [ $t -lt $((max_s * 10)) ]; do
  opened=$(stat_value sessions_opened); cur=$(stat_value session)
  [ "${opened:-0}" -ge 1 ] && [ "$cur" = 0 ] && break
  usleep 100000
  t=$((t + 1))
done
expect "the key holder opened and closed a session" "$(stat_value sessions_opened)" -ge 1
echo "HAP-CPU uptime_s=$up0..$(cut -d' ' -f1 /proc/uptime) bridge_ns=$(( $(bridge_ns) - b0 )) cpu_before=[$c0] cpu_after=[$(cpu_line)]"
usleep 500000
echo "HAP-STATS-BEGIN"; cat /dev/hap_stats; echo "HAP-STATS-END"
kill -USR1 "$bp" 2>/dev/null; usleep 300000
echo "HAP-PROTO-BEGIN"; cat /run/proto_interface.stats 2>/dev/null; echo "HAP-PROTO-END"
echo "HAP-UDP $(awk '/^Udp:/ { if (!h) { split($0, k); h = 1 } else { for (i = 2; i <= NF; i++) printf "%s=%s ", k[i], $i } }' /proc/net/snmp)"
echo "HAP-BRIDGE-SCHED $(cut -d' ' -f41 /proc/$bp/stat 2>/dev/null)"
# The receiving thread's own policy (it leaves SCHED_FIFO while over its
# real-time budget and comes back after).
for t in /proc/$bp/task/*; do
  [ "$(cat $t/comm 2>/dev/null)" = SERVER ] && echo "HAP-SERVER-SCHED $(sed 's/^.*) //' $t/stat | cut -d' ' -f39)"
done
echo "HAP-PROTO-LOG-BEGIN"; cat /run/proto_interface.log 2>/dev/null | head -40; echo "HAP-PROTO-LOG-END"
check "launch script stops cleanly" hapticctrl.sh stop
finish
