#!/bin/sh
# qemu: --icount --timeout 300 --extra tests/data/push.eff:/data/push.eff
# The kernel adds no arithmetic of its own: the same scripted effort run in
# the guest's SERVO and through hap-core in userspace gives the same position
# log, bit for bit.
. /tests/lib.sh
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
sleep 0.2
check "load the effort sequence" dd if=/data/push.eff of=/dev/hap_effort bs=64k count=1
k=$(stat_value effort_loaded_cycle)
echo "# effort loaded at cycle $k"
expect "load cycle recorded" "$k" -gt 0
check_not "a malformed sequence is refused" sh -c 'printf "0 1 2 3\n" > /dev/hap_effort'
check "dmesg gives its line and column" dmesg_has 'effort sequence refused: line 1 column'
sleep 2
hapdev simlog --raw /tmp/guest.bin > /tmp/log.txt
sed 's/^/# /' /tmp/log.txt
expect "records captured" "$(sed -n 's/^records: //p' /tmp/log.txt)" -ge $(cycles_in 2000)
expect "the user moved the handle (um)" "$(sed -n 's/^handle_moved_um: \([0-9]*\).*/\1/p' /tmp/log.txt)" -ge 1000
hapdev replay-compare --effort /data/push.eff --load-cycle "$k" --guest /tmp/guest.bin --period-us $HAP_PERIOD_US > /tmp/cmp.txt
rc=$?
sed 's/^/# /' /tmp/cmp.txt
expect "every guest record equals hap-core's replay" "$rc" = 0
expect "no misses (replay assumes the main path)" "$(stat_value misses)" = 0
check "rmmod" rmmod hapticctrl
finish
