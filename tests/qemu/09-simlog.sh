#!/bin/sh
# qemu: --icount --timeout 300
# The position log of a whole session: `hapctl log` drains /dev/hap_simlog
# from insmod to the fail-safe; a reader stopped for longer than the ring
# (2048 records) loses records, and both the recorder (gaps in the cycle
# count) and the module (simlog.dropped) say how many; each fail-safe step
# adds a record; the recorder ends at end of file. Then with SERVO hung
# inside its cycle: the step records say its state is unknown.
. /tests/lib.sh
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
hapctl log --out /tmp/run.bin --summary /tmp/run.txt 2>/dev/null &
rec=$!
check "power on" sh -c 'echo 1 > /dev/hap_power'
sleep_cycles 500
check "the recorder is running" kill -0 $rec
# The reader stalls for 3000 cycles: the ring holds 2048 and refuses the rest.
check "stop the recorder" kill -STOP $rec
sleep_cycles 3000
expect "the module counted dropped records" "$(stat_value simlog.dropped)" -gt 0
check "resume the recorder" kill -CONT $rec
sleep_cycles 500
check "stop request (fail-safe)" sh -c 'echo stop > /dev/hap_stop'
wait $rec
expect "the recorder ended at end of file" "$?" = 0
sed 's/^/# /' /tmp/run.txt
v() { sed -n "s/^$1: *\([^ ]*\).*/\1/p" /tmp/run.txt | head -1; }
records=$(v records)
expect "records written whole" "$(stat -c %s /tmp/run.bin)" = $((records * 560))
expect "from the calibration cycle" "$(v first_cycle)" = 0
expect "the recorder saw a gap" "$(v dropped_records)" -gt 0
expect "the gap is what the module dropped" "$(v dropped_records)" = "$(v module.simlog.dropped)"
expect "every cycle is either recorded or counted as dropped" \
  "$(( $(v last_cycle) + 1 ))" = "$(( records - $(v fail_safe_records) + $(v dropped_records) ))"
expect "one record per fail-safe step" "$(v fail_safe_records)" = 5
expect "an idle SERVO's state is in every step record" "$(v fail_safe_pose_unknown)" = 0
expect "no undecodable record" "$(v undecodable_records)" = 0
check "rmmod" rmmod hapticctrl

# SERVO hangs inside its cycle holding its data: the fail-safe's step
# records cannot read its state without waiting, and say so (flag
# POSE_UNKNOWN) instead of a pose of 0; the recorder still ends at end of file.
check "insmod again" insmod $HAP_KO period_us=$HAP_PERIOD_US
hapctl log --out /tmp/hang.bin --summary /tmp/hang.txt 2>/dev/null &
rec=$!
check "power on" sh -c 'echo 1 > /dev/hap_power'
sleep_cycles 200
check "inject a hang" sh -c 'echo hang > /dev/hap_fault'
sleep_cycles 60
expect "state is fail_safe" "$(stat_value state)" = fail_safe
wait $rec
expect "the recorder ended at end of file" "$?" = 0
sed 's/^/# /' /tmp/hang.txt
h() { sed -n "s/^$1: *\([^ ]*\).*/\1/p" /tmp/hang.txt | head -1; }
expect "one record per fail-safe step" "$(h fail_safe_records)" = 5
expect "each says SERVO's state is unknown" "$(h fail_safe_pose_unknown)" = 5
expect "nothing dropped" "$(h dropped_records)" = 0
check "rmmod releases the hung SERVO" rmmod hapticctrl
finish
