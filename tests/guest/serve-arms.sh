#!/bin/sh
# In-guest side of the two-arm link run (tests/e2e/two-arms.sh): start the
# controller with arms=2 (a bridge for each arm, UDP 5000 and 5001), load the
# user's effort on both arms, record both position logs, and follow both
# arms every 100 ms of guest time: the cycles each spends coupled, the first
# sample where arm 0 fades (its client's link lost) with arm 1's status in
# the same sample, and when the bridge closes arm 0's silent session. The
# host acts on the markers it prints:
#   HAP-ARM0-COUPLED N   arm 0 has been coupled N >= NEED cycles (the host
#                        then cuts arm 0's client off: SIGKILL, no close)
#   HAP-FADE ...         arm 0 seen fading; arm 1's status in that sample
#   HAP-ARM1-DONE N      arm 0's session closed by its bridge, arm 1 coupled
#                        N >= NEED cycles (the host then ends arm 1's client,
#                        which closes its session)
# Then it prints both arms' and both bridges' statistics and the position
# logs' summaries between markers, and stops: one stop request cuts both
# motor lines.
#   serve-arms.sh PERIOD_US MAX_SECONDS NEED
. /tests/lib.sh
period=${1:-1000}
max_s=${2:-300}
need=${3:-11000}
check "launch script: two arms, a bridge for each" hapticctrl.sh start --period-us "$period" arms=2
hapctl --arm 0 log --out /tmp/sim0.bin --summary /tmp/simlog0.txt 2>/dev/null &
log0=$!
hapctl --arm 1 log --out /tmp/sim1.bin --summary /tmp/simlog1.txt 2>/dev/null &
log1=$!
for d in hap_effort hap1_effort; do
  if [ -f /data/effort.eff ]; then
    check "load the user's effort sequence on /dev/$d" dd if=/data/effort.eff of=/dev/$d bs=64k count=1
  else
    check "the user grips /dev/$d's handle" sh -c "echo 'live 0 0 0 0 0 0' > /dev/$d"
  fi
done
p0=$(cat /run/proto_interface.pid); p1=$(cat /run/proto_interface1.pid)
echo "HAP-READY period_us=$period arms=2"
# coupled: the status bit COUPLED; fading: LINK_FADING (hap_core::vp::status).
coupled=128; fading=256
c0=0; c1=0; prev_cyc=""; prev_st0=0; prev_st1=0
said0=0; faded=0; closed0=0; said1=0
t=0
while [ $t -lt $((max_s * 10)) ]; do
  cat /dev/hap_stats > /tmp/a0; cat /dev/hap1_stats > /tmp/a1
  cyc=$(stat_value cycles /tmp/a0)
  st0=$(stat_value status /tmp/a0); st1=$(stat_value status /tmp/a1)
  ses0=$(stat_value session /tmp/a0); ses1=$(stat_value session /tmp/a1)
  # A sample pair counts its cycles for an arm coupled at both ends.
  if [ -n "$prev_cyc" ]; then
    [ $((prev_st0 & st0 & coupled)) -ne 0 ] && c0=$((c0 + cyc - prev_cyc))
    [ $((prev_st1 & st1 & coupled)) -ne 0 ] && c1=$((c1 + cyc - prev_cyc))
  fi
  prev_cyc=$cyc; prev_st0=$st0; prev_st1=$st1
  if [ $said0 = 0 ] && [ $c0 -ge "$need" ]; then
    echo "HAP-ARM0-COUPLED $c0"; said0=1
  fi
  if [ $said0 = 1 ] && [ $faded = 0 ] && [ "${ses0:-0}" != 0 ] && [ $((st0 & fading)) -ne 0 ]; then
    echo "HAP-FADE cycle=$cyc arm0_status=$st0 arm1_status=$st1 arm1_session=$ses1"; faded=1
  fi
  if [ $faded = 1 ] && [ $closed0 = 0 ] && [ "${ses0:-0}" = 0 ]; then
    echo "HAP-ARM0-CLOSED cycle=$cyc arm1_status=$st1 arm1_session=$ses1"; closed0=1
  fi
  if [ $closed0 = 1 ] && [ $said1 = 0 ] && [ $c1 -ge "$need" ]; then
    echo "HAP-ARM1-DONE $c1"; said1=1
  fi
  [ $said1 = 1 ] && [ "${ses1:-0}" = 0 ] && break
  # A controller in fail-safe serves no session any more.
  [ "$(stat_value state /tmp/a0)" = fail_safe ] && break
  usleep 100000
  t=$((t + 1))
done
echo "HAP-COUPLED arm0=$c0 arm1=$c1"
expect "arm 1's client closed its session" "$said1,${ses1:-x}" = "1,0"
usleep 500000
for a in 0 1; do
  case $a in 0) d=/dev/hap_stats ;; 1) d=/dev/hap1_stats ;; esac
  echo "HAP-STATS$a-BEGIN"; cat $d; echo "HAP-STATS$a-END"
done
kill -USR1 "$p0" "$p1" 2>/dev/null; usleep 300000
s0=/run/proto_interface.stats
s1=$(dirname "$(readlink -f $s0)")/proto_interface1.stats
echo "HAP-PROTO0-BEGIN"; cat $s0 2>/dev/null; echo "HAP-PROTO0-END"
echo "HAP-PROTO1-BEGIN"; cat "$s1" 2>/dev/null; echo "HAP-PROTO1-END"
# One stop request: both arms' motor lines cut, both position logs closed
# (their recorders drain them and exit).
echo 1 > /dev/hap_stop
wait "$log0"
expect "arm 0's position log recorder ended cleanly" "$?" = 0
wait "$log1"
expect "arm 1's position log recorder ended cleanly" "$?" = 0
expect "arm 0's line cut" "$(sed -n 's/.*gate=\([a-z_]*\).*/\1/p' /dev/hap_power)" = fail_safe
expect "arm 1's line cut" "$(sed -n 's/.*gate=\([a-z_]*\).*/\1/p' /dev/hap1_power)" = fail_safe
for a in 0 1; do
  echo "HAP-SIMLOG$a-SUMMARY-BEGIN"; cat /tmp/simlog$a.txt; echo "HAP-SIMLOG$a-SUMMARY-END"
done
echo "HAP-CUT-BEGIN"
dmesg | sed -n 's/.*fail-safe (stop_requested): step \([0-9]\)\/5: [a-z_]* (arm \([01]\), .*gate \([a-z_]*\), supply \([01]\).*/\1 \2 \3 \4/p'
echo "HAP-CUT-END"
check "launch script stops cleanly" hapticctrl.sh stop
check_not "the module is unloaded" sh -c 'grep -q ^hapticctrl /proc/modules'
finish
