#!/bin/sh
# qemu: --icount --timeout 300
# Deadline supervision: 4 consecutive overruns put SERVO on its degraded path
# and the cycle recovers; exactly 5 consecutive overruns drive the fail-safe.
. /tests/lib.sh
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
sleep_cycles 300
expect "no miss before injection" "$(stat_value misses)" = 0
check_not "fault device refuses 'overrun 0'" sh -c 'echo "overrun 0" > /dev/hap_fault'
check_not "fault device refuses garbage" sh -c 'echo "boom" > /dev/hap_fault'

check "inject 4 overruns" sh -c 'echo "overrun 4" > /dev/hap_fault'
sleep_cycles 20
expect "4 misses counted" "$(stat_value misses)" = 4
expect "max consecutive misses is 4" "$(stat_value max_consecutive_misses)" = 4
expect "still running" "$(stat_value state)" = running
expect "degraded cycles counted" "$(stat_value degraded_cycles)" -ge 4
sleep_cycles 300
expect "mode back to normal after the good cycles" "$(stat_value mode)" = normal
expect "no further miss" "$(stat_value misses)" = 4

check "inject 4 again, separated: no fail-safe" sh -c 'echo "overrun 4" > /dev/hap_fault'
sleep_cycles 20
expect "8 misses, never 5 in a row" "$(stat_value max_consecutive_misses)" = 4
expect "still running" "$(stat_value state)" = running

check "inject 5 overruns" sh -c 'echo "overrun 5" > /dev/hap_fault'
sleep_cycles 30
expect "state is fail_safe" "$(stat_value state)" = fail_safe
expect "max consecutive misses is exactly 5" "$(stat_value max_consecutive_misses)" = 5
check "dmesg: fail-safe caused by the miss limit" dmesg_has 'fail-safe \(miss_limit\): start'
dmesg | sed -n 's/.*fail-safe (miss_limit): step \([0-9]\)\/5: \([a-z_]*\).*/\2/p' | tr '\n' ',' > /tmp/order.txt
expect "step order" "$(cat /tmp/order.txt)" = "inhibit_motor_commands,power_off_arm,close_protocol,stop_tasks,release_resources,"
check "rmmod" rmmod hapticctrl
finish
