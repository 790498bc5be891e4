#!/bin/sh
# In-guest real-time benchmark (scripts/bench-rt.sh boots it; not part of the
# test suite). Args: CYCLES [cyclictest].
# Phase "idle": insmod, N servo cycles with nothing else running, stats dump.
# Phase "load": insmod again, N cycles under a heavy userspace load, all
# SCHED_OTHER nice 0: stress-ng (cpu, vm, io, hdd stressors) and a hackbench
# loop (scheduler/IPC load) when the host script added them, else busybox
# busy loops, dd and a fork storm; stats dump, load killed.
# With "cyclictest" (binary + libs added by the host script), cyclictest runs
# at the same period and SCHED_FIFO 80 next to the module in each phase, with
# a 1 us histogram like /dev/hap_hist's.
# Dumps are between "BENCH-BEGIN <phase>" / "BENCH-END <phase>" markers
# (stats, cyclictest summary) and "HIST-BEGIN <phase>" / "HIST-END <phase>"
# (/dev/hap_hist, cyclictest's histogram as "cthist: US COUNT"); the host
# script parses them. Figures only, no assertions on timing.
. "${HAP_TESTS_LIB:-/tests/lib.sh}"
# cyclictest wants POSIX shared memory (a real machine has it already).
grep -q ' /dev/shm ' /proc/mounts || { mkdir -p /dev/shm && mount -t tmpfs shm /dev/shm 2>/dev/null; }
N=${1:-100000}
CT=${2:-}
echo "# bench: mode $HAP_MODE, period $HAP_PERIOD_US us, $N cycles per phase"

# cpu_sample: "total idle" jiffies from /proc/stat (to show the load ran).
cpu_sample() {
  # shellcheck disable=SC2046
  set -- $(head -1 /proc/stat)
  echo "$(($2 + $3 + $4 + $5 + $6 + $7 + $8)) $5"
}

phase() {
  name=$1
  check "$name: insmod period_us=$HAP_PERIOD_US" insmod $HAP_KO period_us=$HAP_PERIOD_US
  [ "$name" = load ] && start_load
  ctpid=""
  if [ -n "$CT" ]; then
    cyclictest -m -p 80 -i "$HAP_PERIOD_US" -l "$N" -q -h 1000 --histfile=/tmp/cth.$name > /tmp/ct.$name 2>&1 &
    ctpid=$!
  fi
  t0=$(now_ms)
  s0=$(cpu_sample)
  c=$(stat_value cycles)
  while [ "${c:-0}" -lt "$N" ]; do
    sleep 1
    c=$(stat_value cycles)
  done
  t1=$(now_ms)
  s1=$(cpu_sample)
  # Snapshot at once (the stats keep counting while the shell works).
  cat /dev/hap_stats > /tmp/stats.$name
  cat /dev/hap_hist > /tmp/hist.$name
  [ -n "$ctpid" ] && wait "$ctpid"
  [ "$name" = load ] && stop_load
  echo "BENCH-BEGIN $name"
  echo "guest_ms: $((t1 - t0))"
  # shellcheck disable=SC2086
  set -- $s0 $s1
  [ "$3" -gt "$1" ] && echo "cpu_busy_pct: $(( 100 - 100 * ($4 - $2) / ($3 - $1) ))"
  echo "loadavg: $(cut -d' ' -f1-3 /proc/loadavg)"
  [ "$name" = load ] && echo "load_kind: $LOAD_KIND"
  cat /tmp/stats.$name
  if [ -n "$CT" ]; then
    sed 's/^/cyclictest: /' /tmp/ct.$name
    grep '^#' /tmp/cth.$name | sed 's/^/cyclictest: /'
  fi
  echo "BENCH-END $name"
  echo "HIST-BEGIN $name"
  grep -v '^#' /tmp/hist.$name
  # cyclictest's histogram, non-zero buckets only.
  [ -n "$CT" ] && awk '!/^#/ && $2 + 0 > 0 { print "cthist: " $1 + 0 " " $2 + 0 }' /tmp/cth.$name
  echo "HIST-END $name"
  check "$name: rmmod" rmmod hapticctrl
}

if [ -n "$CT" ]; then
  check "cyclictest runs in the guest" cyclictest -m -p 80 -i "$HAP_PERIOD_US" -l 10 -q
  grep -q . /tmp/check.out || CT=""
  sed 's/^/# cyclictest probe: /' /tmp/check.out
fi
phase idle
phase load
finish
