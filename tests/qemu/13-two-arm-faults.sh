#!/bin/sh
# qemu: --icount --timeout 300 --extra tests/data/push.eff:/data/push.eff
# Faults with two arms (arms=2). Hostile frames on arm 1's rtf_in never
# touch arm 0's state: arm 0's counters do not move and its position log,
# recorded meanwhile, equals bit for bit hap-core's replay of arm 0 alone.
# Five consecutive deadline misses cut both motor lines, in order: every
# arm inhibited (step 1, still supplied) before any is powered off (step 2),
# and from the cut on both lines apply exactly 0.
. /tests/lib.sh
ZERO="0,0,0,0,0,0"
applied() { sed -n 's/.* applied=\([-0-9,]*\).*/\1/p' "$1"; }
check "insmod arms=2" insmod $HAP_KO period_us=$HAP_PERIOD_US arms=2
sleep 0.2

echo "# --- 1. hostile frames on arm 1, arm 0 replays its effort sequence"
check "load the effort sequence on arm 0" dd if=/data/push.eff of=/dev/hap_effort bs=64k count=1
k0=$(stat_value effort_loaded_cycle /dev/hap_stats)
cat /dev/hap_stats > /tmp/before0
q0=$(stat_value frames_rejected /dev/hap1_stats)
check "1000 random frames into arm 1's rtf_in" hapdev --rtf-in /dev/hap1_rtf_in send garbage 1000
check "a frame with a bad CRC into arm 1's rtf_in" hapdev --rtf-in /dev/hap1_rtf_in send badcrc
check_not "a short frame: arm 1's rtf_in refuses the write" hapdev --rtf-in /dev/hap1_rtf_in send short
check "2000 hostile frames (hap-core built: wrong session, sequence, sizes) into arm 1's rtf_in" \
  hapdev --rtf-in /dev/hap1_rtf_in hostile dev --session 1 --count 2000 --interval-us 200
sed 's/^/# /' /tmp/check.out | tail -12
sleep_cycles 200
cat /dev/hap_stats > /tmp/after0
expect "arm 1 rejected the hostile frames" $(( $(stat_value frames_rejected /dev/hap1_stats) - q0 )) -ge 1002
for c in frames_in frames_rejected frames_out sessions_opened replies; do
  expect "arm 0's $c unchanged" "$(stat_value $c /tmp/after0)" = "$(stat_value $c /tmp/before0)"
done
expect "arm 0: no frame at all" "$(stat_value frames_in /tmp/after0),$(stat_value frames_rejected /tmp/after0)" = "0,0"
sleep 2
hapdev simlog --dev /dev/hap_simlog --raw /tmp/guest0.bin > /tmp/log0.txt
sed 's/^/# arm 0: /' /tmp/log0.txt
expect "arm 0: records captured" "$(sed -n 's/^records: //p' /tmp/log0.txt)" -ge $(cycles_in 2000)
hapdev replay-compare --effort /data/push.eff --load-cycle "$k0" --guest /tmp/guest0.bin --period-us $HAP_PERIOD_US > /tmp/cmp0.txt
rc=$?
sed 's/^/# arm 0: /' /tmp/cmp0.txt
expect "arm 0: every record equals hap-core's replay of arm 0 alone" "$rc" = 0
expect "no misses so far" "$(stat_value misses)" = 0

echo "# --- 2. five consecutive misses cut both motor lines, in order"
check "power on arm 0" sh -c 'echo 1 > /dev/hap_power'
check "power on arm 1" sh -c 'echo 1 > /dev/hap1_power'
sleep_cycles 200
expect "both powered" "$(stat_value power /dev/hap_stats),$(stat_value power /dev/hap1_stats)" = "1,1"
expect "arm 0's line carries a torque" "$(applied /dev/hap_power)" != "$ZERO"
expect "arm 1's line carries a torque" "$(applied /dev/hap1_power)" != "$ZERO"
check "inject 5 overruns" sh -c 'echo "overrun 5" > /dev/hap_fault'
sleep_cycles 60
expect "state is fail_safe" "$(stat_value state)" = fail_safe
expect "exactly 5 consecutive misses" "$(stat_value max_consecutive_misses)" = 5
dmesg | sed -n 's/.*fail-safe (miss_limit): step \([0-9]\)\/5: [a-z_]* (arm \([01]\), .*gate \([a-z_]*\), supply \([01]\), applied torque \([0-9]*\).*/\1 \2 \3 \4 \5/p' > /tmp/cut.txt
sed 's/^/# step arm gate supply applied: /' /tmp/cut.txt
expect "step 1 inhibits arm 0, then arm 1, both still supplied, 0 applied" "$(sed -n 1,2p /tmp/cut.txt | tr '\n' ,)" = "1 0 fail_safe 1 0,1 1 fail_safe 1 0,"
expect "step 2 powers off arm 0, then arm 1" "$(sed -n 3,4p /tmp/cut.txt | tr '\n' ,)" = "2 0 fail_safe 0 0,2 1 fail_safe 0 0,"
for a in 0 1; do
  case $a in 0) p=/dev/hap_power; l=/dev/hap_simlog ;; 1) p=/dev/hap1_power; l=/dev/hap1_simlog ;; esac
  expect "arm $a's line cut" "$(sed -n 's/.* gate=\([a-z_]*\) .*/\1/p' $p)" = fail_safe
  expect "arm $a's line applies 0" "$(applied $p)" = "$ZERO"
  hapdev simlog --dev $l --raw /tmp/cut$a.bin > /tmp/cutlog$a.txt
  expect "arm $a's log: torque exactly 0 from the cut on" "$(sed -n 's/^torque_nonzero_from_cut: //p' /tmp/cutlog$a.txt)" = 0
  expect "arm $a's log: every record from the cut on is flagged" "$(sed -n 's/^unflagged_after_cut: //p' /tmp/cutlog$a.txt)" = 0
done
check "rmmod" rmmod hapticctrl
finish
