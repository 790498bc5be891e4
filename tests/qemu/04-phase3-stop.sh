#!/bin/sh
# qemu: --icount --timeout 240
# Spec §4.1 phase 3: a termination request drives the fail-safe, in order:
# inhibit motor commands, power off the arm, close the protocol, stop the
# tasks; then the module unloads cleanly. Also: rmmod while a reader blocks.
. /tests/lib.sh
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
check "power on" sh -c 'echo 1 > /dev/hap_power'
sleep_cycles 50
expect "powered" "$(stat_value power)" = 1

# A reader blocked on rtf_out (no session: nothing to read).
cat /dev/hap_rtf_out > /tmp/rtf_out.bin &
reader=$!
sleep 0.2
check "the reader is blocked" kill -0 $reader
check_not "rmmod while a reader holds rtf_out fails at once (no hang)" rmmod hapticctrl
check "the module is still there" sh -c 'grep -q ^hapticctrl /proc/modules'

check "stop request" sh -c 'echo stop > /dev/hap_stop'
sleep_cycles 50
expect "state is fail_safe" "$(stat_value state)" = fail_safe
check "dmesg: fail-safe caused by the stop request" dmesg_has 'fail-safe \(stop_requested\): start'
# The five steps, in hap-core's order.
dmesg | sed -n 's/.*fail-safe (stop_requested): step \([0-9]\)\/5: \([a-z_]*\).*/\1 \2/p' > /tmp/steps.txt
sed 's/^/# step /' /tmp/steps.txt
expect "five steps logged" "$(wc -l < /tmp/steps.txt)" = 5
expect "step order" "$(awk '{printf "%s,", $2}' /tmp/steps.txt)" = "inhibit_motor_commands,power_off_arm,close_protocol,stop_tasks,release_resources,"
expect "motors inhibited" "$(stat_value motors_inhibited)" = 1
expect "arm powered off" "$(stat_value power)" = 0
sleep 0.3
check_not "the blocked reader saw end of file and exited" kill -0 $reader
c0=$(stat_value timer_ticks); sleep_cycles 50; c1=$(stat_value timer_ticks)
expect "the cycle is stopped" "$c1" = "$c0"
check_not "a power-on request after the fail-safe does not re-enable motors" sh -c 'echo 1 > /dev/hap_power; sleep 0.1; grep -q "^motors_enabled: 1" /dev/hap_stats'
hapdev simlog > /tmp/post.txt
expect "the position log stays readable after the fail-safe (post-mortem)" "$(sed -n 's/^records: //p' /tmp/post.txt)" -gt 10
check "rmmod after the fail-safe" rmmod hapticctrl
check "dmesg: unloaded" dmesg_has 'hapticctrl: unloaded'
finish
