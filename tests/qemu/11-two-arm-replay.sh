#!/bin/sh
# qemu: --icount --timeout 300 --extra tests/data/push.eff:/data/push.eff
# Two arms, one SERVO: each arm's position log equals, bit for bit, hap-core's
# replay of that arm alone on the host (the same effort sequence, loaded on
# each arm at its own cycle): stepping a second arm in the same period
# changes nothing in the first's cycle, and the arms share no state.
. /tests/lib.sh
check "insmod arms=2" insmod $HAP_KO period_us=$HAP_PERIOD_US arms=2
sleep 0.2
check "load the effort sequence on arm 0" dd if=/data/push.eff of=/dev/hap_effort bs=64k count=1
sleep_cycles 37
check "load it on arm 1, later" dd if=/data/push.eff of=/dev/hap1_effort bs=64k count=1
k0=$(stat_value effort_loaded_cycle /dev/hap_stats)
k1=$(stat_value effort_loaded_cycle /dev/hap1_stats)
echo "# effort loaded at cycle $k0 (arm 0), $k1 (arm 1)"
expect "arm 1 loaded after arm 0" "$k1" -gt "$k0"
sleep 2
for a in 0 1; do
  case $a in 0) d=/dev/hap_simlog; k=$k0 ;; 1) d=/dev/hap1_simlog; k=$k1 ;; esac
  hapdev simlog --dev $d --raw /tmp/guest$a.bin > /tmp/log$a.txt
  sed "s/^/# arm $a: /" /tmp/log$a.txt
  expect "arm $a: records captured" "$(sed -n 's/^records: //p' /tmp/log$a.txt)" -ge $(cycles_in 2000)
  expect "arm $a: the user moved the handle (um)" "$(sed -n 's/^handle_moved_um: \([0-9]*\).*/\1/p' /tmp/log$a.txt)" -ge 1000
  hapdev replay-compare --effort /data/push.eff --load-cycle "$k" --guest /tmp/guest$a.bin --period-us $HAP_PERIOD_US > /tmp/cmp$a.txt
  rc=$?
  sed "s/^/# arm $a: /" /tmp/cmp$a.txt
  expect "arm $a: every guest record equals hap-core's replay" "$rc" = 0
done
expect "the two logs differ (each arm its own history)" "$(cmp -s /tmp/guest0.bin /tmp/guest1.bin; echo $?)" = 1
expect "no misses (replay assumes the main path)" "$(stat_value misses)" = 0
check "rmmod" rmmod hapticctrl
finish
