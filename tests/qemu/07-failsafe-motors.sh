#!/bin/sh
# qemu: --icount --timeout 300
# The fail-safe at the motors, under the real faults: SERVO overruns inside
# its cycle holding mtx_data (then finishes late), and SERVO hangs inside its
# cycle holding mtx_data and never finishes. In both, the motors apply
# exactly 0 from the fail-safe's first step on (read from the motor line and
# from the position log), and the fail-safe completes in order without SERVO.
. /tests/lib.sh

# applied_torques: the "applied=" field of /dev/hap_power (six µN·m values).
applied_torques() { sed -n 's/.* applied=\([-0-9,]*\).*/\1/p' /dev/hap_power; }
command_torques() { sed -n 's/.* command=\([-0-9,]*\) .*/\1/p' /dev/hap_power; }
summary_value() { sed -n "s/^$1: //p" /tmp/simlog.txt; }
steps_of() { dmesg | sed -n "s/.*fail-safe ($1): step \([0-9]\)\/5: \([a-z_]*\).*/\2/p" | tr '\n' ','; }
ORDER="inhibit_motor_commands,power_off_arm,close_protocol,stop_tasks,release_resources,"
ZERO="0,0,0,0,0,0"

echo "# --- 1. five overruns inside the cycle, mtx_data held"
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
check "power on" sh -c 'echo 1 > /dev/hap_power'
sleep_cycles 200
expect "powered" "$(stat_value power)" = 1
check "gravity compensation puts a non-zero torque on the line" sh -c "! grep -q ' applied=$ZERO' /dev/hap_power"
check "inject 5 overruns" sh -c 'echo "overrun 5" > /dev/hap_fault'
sleep_cycles 60
expect "state is fail_safe" "$(stat_value state)" = fail_safe
expect "exactly 5 consecutive misses" "$(stat_value max_consecutive_misses)" = 5
expect "step order" "$(steps_of miss_limit)" = "$ORDER"
check "dmesg: the line was cut while SERVO was inside its cycle" \
  dmesg_has 'fail-safe \(miss_limit\): step 1/5: inhibit_motor_commands \(servo in cycle, gate fail_safe, supply 1, applied torque 0\)'
check "dmesg: supply off at step 2" dmesg_has 'step 2/5: power_off_arm \(.*gate fail_safe, supply 0, applied torque 0\)'
expect "the motor line: gate cut" "$(sed -n 's/.* gate=\([a-z_]*\) .*/\1/p' /dev/hap_power)" = fail_safe
expect "the motor line applies 0" "$(applied_torques)" = "$ZERO"
hapdev simlog --raw /tmp/overrun.bin > /tmp/simlog.txt
sed 's/^/# /' /tmp/simlog.txt
expect "log: non-zero torque before the cut" "$(summary_value torque_nonzero_before_cut)" -gt 100
expect "log: SERVO's late cycle ran on the cut line" "$(summary_value servo_records_from_cut)" -ge 1
expect "log: torque exactly 0 from the cut on" "$(summary_value torque_nonzero_from_cut)" = 0
expect "log: every record from the cut on is flagged" "$(summary_value unflagged_after_cut)" = 0
check "rmmod" rmmod hapticctrl

echo "# --- 2. SERVO hangs inside its cycle, mtx_data held, and never returns"
dmesg -c > /dev/null
check "insmod again" insmod $HAP_KO period_us=$HAP_PERIOD_US
check "power on" sh -c 'echo 1 > /dev/hap_power'
sleep_cycles 200
check "non-zero torque on the line" sh -c "! grep -q ' applied=$ZERO' /dev/hap_power"
check "inject a hang" sh -c 'echo hang > /dev/hap_fault'
sleep_cycles 60
expect "state is fail_safe" "$(stat_value state)" = fail_safe
expect "step order, without SERVO" "$(steps_of miss_limit)" = "$ORDER"
check "dmesg: the line was cut while SERVO was hung in its cycle" \
  dmesg_has 'step 1/5: inhibit_motor_commands \(servo in cycle, gate fail_safe, supply 1, applied torque 0\)'
check "dmesg: SERVO never finished" dmesg_has 'fail-safe \(miss_limit\): SERVO still inside its cycle'
# The DAC still holds the hung cycle's last command: the fault is real, and
# only the cut line keeps it from the motors.
check "the DAC still holds a non-zero command" sh -c "[ \"\$(sed -n 's/.* command=\([-0-9,]*\) .*/\1/p' /dev/hap_power)\" != $ZERO ]"
ok=0
for i in 1 2 3 4 5; do
  [ "$(applied_torques)" = "$ZERO" ] && ok=$((ok + 1))
  sleep_cycles 20
done
expect "the motors apply 0 at every look over 100 periods" "$ok" = 5
hapdev simlog --raw /tmp/hang.bin > /tmp/simlog.txt
sed 's/^/# /' /tmp/simlog.txt
expect "log: non-zero torque before the hang" "$(summary_value torque_nonzero_before_cut)" -gt 100
expect "log: no record with torque from the cut on" "$(summary_value torque_nonzero_from_cut)" = 0
expect "log: the hung SERVO logged no cycle after the cut" "$(summary_value servo_records_from_cut)" = 0
check "rmmod releases the hung SERVO" rmmod hapticctrl
check "dmesg: unloaded" dmesg_has 'hapticctrl: unloaded'
finish
