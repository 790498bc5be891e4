#!/bin/sh
# qemu: --icount --timeout 300
# The launch script with arms=2: a bridge for each arm, each on its own UDP
# port with its own devices and counters; stop ends both and the module.
. /tests/lib.sh
export HAP_INSECURE=1
# The clients here are on the guest's loopback.
ip link set lo up 2>/dev/null || ifconfig lo 127.0.0.1 up
check "launch script: two arms, a bridge for each" hapticctrl.sh start --period-us $HAP_PERIOD_US arms=2
# (the script's warning about the unauthenticated bridge is left out: the
# guest log's scan would take it for a kernel warning)
grep -v 'WARNING' /tmp/check.out | sed 's/^/# /'
check "arm 0's bridge runs" sh -c 'kill -0 $(cat /run/proto_interface.pid)'
check "arm 1's bridge runs" sh -c 'kill -0 $(cat /run/proto_interface1.pid)'
check "arm 1's FIFOs given to the bridge's group" sh -c 'ls -l /dev/hap1_rtf_in | grep -q "^crw-rw----"'
sleep 2
# Each bridge's counters: arm 0's where they always were, arm 1's next to them.
s0=/run/proto_interface.stats
s1=$(dirname "$(readlink -f $s0)")/proto_interface1.stats
echo "# counters: $s0, $s1"
b0=$(stat_value received $s0); b1=$(stat_value received $s1)
echo "# received before: arm 0 $b0, arm 1 $b1"
check "200 stray datagrams to arm 1's port (5001)" hapdev hostile net --to 127.0.0.1:5001 --count 200 --interval-us 500
sleep 2
expect "arm 1's bridge received them" $(( $(stat_value received $s1) - b1 )) = 200
expect "arm 0's bridge received none of them" "$(stat_value received $s0)" = "$b0"
check "50 stray datagrams to arm 0's port (5000)" hapdev hostile net --to 127.0.0.1:5000 --count 50 --interval-us 500
sleep 2
expect "arm 0's bridge received them" $(( $(stat_value received $s0) - b0 )) = 50
expect "arm 1's bridge received no more" $(( $(stat_value received $s1) - b1 )) = 200
expect "no deadline miss" "$(stat_value misses)" = 0
p0=$(cat /run/proto_interface.pid); p1=$(cat /run/proto_interface1.pid)
check "launch script: stop" hapticctrl.sh stop
sed 's/^/# /' /tmp/check.out
# The fail-safe closes both arms' FIFOs: a bridge that sees it exits by
# itself, the script stops the other.
check_not "arm 0's bridge gone" kill -0 "$p0"
check_not "arm 1's bridge gone" kill -0 "$p1"
check_not "no pid file left" ls /run/proto_interface.pid /run/proto_interface1.pid
check_not "module removed" grep -q '^hapticctrl ' /proc/modules
finish
