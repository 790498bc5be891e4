# In-guest test helpers (busybox sh). Source from a test script.
# Every check prints "ok N - what" or "not ok N - what (detail)"; `finish`
# prints "N passed, N failed" and returns non-zero if anything failed.
HT_PASS=0
HT_FAIL=0
HT_N=0
# In the guest these come from the initramfs and the kernel command line;
# scripts/bench-rt.sh --host sets them in the environment instead.
HAP_KO=${HAP_KO:-/lib/modules/hapticctrl.ko}
HAP_MODE=${HAP_MODE:-$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' /proc/cmdline)}
# The servo period the suite runs at (qemu-run.sh --period-us; 1000 by default).
HAP_PERIOD_US=${HAP_PERIOD_US:-$(sed -n 's/.*hap\.period_us=\([0-9]*\).*/\1/p' /proc/cmdline)}
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

# stat_value KEY [FILE]: the value of "KEY: value" in /dev/hap_stats (or in
# FILE, a snapshot of it: counters compared with each other must come from
# one snapshot) (first word).
stat_value() { sed -n "s/^$1: *\([^ ]*\).*/\1/p" "${2:-/dev/hap_stats}" | head -1; }
# dmesg_has PATTERN: the kernel log contains the (grep -E) pattern.
dmesg_has() { dmesg | grep -q -E "$1"; }
# Guest time in ms (monotonic, from /proc/uptime).
now_ms() { awk '{ printf "%d\n", $1 * 1000 }' /proc/uptime; }

# Benchmark load (tests/bench/*, scripts/bench-rt.sh, scripts/soak.sh), all
# SCHED_OTHER nice 0: stress-ng (cpu, vm, io, hdd) and a hackbench loop when
# the host script added them to the initramfs, else busybox busy loops, dd
# and a fork storm. start_load sets LOAD_KIND and LOAD_PIDS; stop_load ends it.
start_load() {
  LOAD_PIDS=""
  if command -v stress-ng >/dev/null && command -v hackbench >/dev/null; then
    LOAD_KIND="stress-ng --cpu 2 --vm 1 --vm-bytes 64M --io 1 --hdd 1 --hdd-bytes 8M + hackbench -g 4 -l 200 loop"
    mkdir -p /tmp/stress
    stress-ng --cpu 2 --vm 1 --vm-bytes 64M --io 1 --hdd 1 --hdd-bytes 8M \
      --temp-path /tmp/stress --timeout 0 > /tmp/stress.out 2>&1 & LOAD_PIDS="$LOAD_PIDS $!"
    sh -c 'while :; do hackbench -g 4 -l 200 -s 100 > /dev/null 2>&1 || exit 1; done' & LOAD_PIDS="$LOAD_PIDS $!"
  else
    LOAD_KIND="busybox: 3 sh busy loops, dd /dev/zero->/dev/null, fork storm"
    for i in 1 2 3; do
      sh -c 'while :; do :; done' & LOAD_PIDS="$LOAD_PIDS $!"
    done
    dd if=/dev/zero of=/dev/null bs=1M 2>/dev/null & LOAD_PIDS="$LOAD_PIDS $!"
    sh -c 'while :; do /bin/true; done' & LOAD_PIDS="$LOAD_PIDS $!"
  fi
  echo "# load started ($LOAD_KIND): pids$LOAD_PIDS"
}
stop_load() {
  # stress-ng's workers are its children: SIGINT lets it reap them and print
  # its summary. Then the hackbench loop.
  # shellcheck disable=SC2086
  kill -INT $LOAD_PIDS 2>/dev/null
  sleep 2
  # shellcheck disable=SC2086
  kill $LOAD_PIDS 2>/dev/null
  wait $LOAD_PIDS 2>/dev/null
  killall -q stress-ng hackbench 2>/dev/null
  echo "# load stopped"
  [ -s /tmp/stress.out ] && sed 's/^/# stress-ng: /' /tmp/stress.out | tail -15
}

