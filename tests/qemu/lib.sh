# In-guest test helpers (busybox sh). Source from a test script.
# Every check prints "ok N - what" or "not ok N - what (detail)"; `finish`
# prints "N passed, N failed" and returns non-zero if anything failed.
HT_PASS=0
HT_FAIL=0
HT_N=0
HAP_KO=/lib/modules/hapticctrl.ko
HAP_MODE=$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' /proc/cmdline)
# The servo period the suite runs at (qemu-run.sh --period-us; 1000 by default).
HAP_PERIOD_US=$(sed -n 's/.*hap\.period_us=\([0-9]*\).*/\1/p' /proc/cmdline)
HAP_PERIOD_US=${HAP_PERIOD_US:-1000}
# cycles_in MS: servo cycles in MS milliseconds at the suite's period.
cycles_in() { echo $(( $1 * 1000 / HAP_PERIOD_US )); }
# sleep_cycles N: sleep for N servo periods.
sleep_cycles() { usleep $(( $1 * HAP_PERIOD_US )); }

pass() { HT_N=$((HT_N + 1)); HT_PASS=$((HT_PASS + 1)); echo "ok $HT_N - $*"; }
fail() { HT_N=$((HT_N + 1)); HT_FAIL=$((HT_FAIL + 1)); echo "not ok $HT_N - $*"; }
# check "description" command args...: passes if the command succeeds.
check() { d=$1; shift; if "$@" >/tmp/check.out 2>&1; then pass "$d"; else fail "$d ($(head -c 300 /tmp/check.out))"; fi; }
# check_not "description" command args...: passes if the command fails.
check_not() { d=$1; shift; if "$@" >/tmp/check.out 2>&1; then fail "$d (unexpectedly succeeded)"; else pass "$d"; fi; }
# expect "description" ACTUAL OP EXPECTED (test(1) operators: -eq -ge -le = ...)
expect() { d=$1; if [ "$2" "$3" "$4" ] 2>/dev/null; then pass "$d ($2 $3 $4)"; else fail "$d (got '$2', want $3 '$4')"; fi; }
finish() { echo "$HT_PASS passed, $HT_FAIL failed"; [ "$HT_FAIL" -eq 0 ]; }

# stat_value KEY: the value of "KEY: value" in /dev/hap_stats (first word).
stat_value() { sed -n "s/^$1: *\([^ ]*\).*/\1/p" /dev/hap_stats | head -1; }
# dmesg_has PATTERN: the kernel log contains the (grep -E) pattern.
dmesg_has() { dmesg | grep -q -E "$1"; }
# Guest time in ms (monotonic, from /proc/uptime).
now_ms() { awk '{ printf "%d\n", $1 * 1000 }' /proc/uptime; }
