#!/usr/bin/env bash
# Real-time benchmark in ONE guest boot (issue 6, first slice):
#   scripts/bench-rt.sh [--cycles N] [--period-us P] [--long] [--no-cyclictest] [--out DIR]
# Boots tests/bench/rt-guest.sh under QEMU TCG icount (--icount): N servo
# cycles idle, then N cycles under a busybox userspace load (3 busy loops,
# dd /dev/zero -> /dev/null, a fork storm), with cyclictest (rt-tests, same
# period, SCHED_FIFO 80) running next to the module in each phase when
# rt-tests is installed on the host. Prints a side-by-side table.
#
# Mode: tcg-icount -- guest time is the guest's instruction count (~1 ns per
# instruction): the figures are deterministic COSTS, not wall-clock latencies
# of real hardware. No KVM on this machine kind (toolchain-notes.md); where
# qemu-run.sh finds a working KVM it uses it, and the report names the mode.
#
# Default N = 10^5 per phase (about 7 min wall here: ~1.9 ms wall per guest
# cycle); --long = 10^6 per phase (about 65 min, not for CI). Results in
# build/bench/rt-*.txt (table) and rt-*.log (guest console).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
cycles=100000; period_us=1000; use_ct=1; out="$ROOT/build/bench"
while [ $# -gt 0 ]; do
  case "$1" in
    --cycles) cycles=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    --long) cycles=1000000 ;;
    --no-cyclictest) use_ct=0 ;;
    --out) out=$2; shift ;;
    -h|--help) awk 'NR > 1 && /^#/ { print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    *) echo "bench-rt: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done
mkdir -p "$out"
stamp=$(date -u +%Y%m%dT%H%M%SZ)
log="$out/rt-$stamp.log"
report="$out/rt-$stamp.txt"

extras=()
ct_arg=""
if [ "$use_ct" = 1 ]; then
  ct=$(command -v cyclictest || true)
  if [ -z "$ct" ]; then
    echo "bench-rt: cyclictest not found (apt-get install -y rt-tests); running without it" >&2
  else
    extras+=(--extra "$ct:/usr/bin/cyclictest")
    # The dynamic libraries and loader ldd lists, at their own paths.
    while read -r lib; do
      extras+=(--extra "$lib:$lib")
    done < <(ldd "$ct" | sed -n -e 's/.*=> \(\/[^ ]*\) .*/\1/p' -e 's/^[[:space:]]*\(\/[^ ]*\) .*/\1/p')
    ct_arg=cyclictest
  fi
fi

[ -f "$ROOT/build/base/module/hapticctrl.ko" ] || make -C "$ROOT"
# Guest time for 2 N cycles plus boot; icount runs well below real time
# under load: allow generously.
timeout_s=$(( 120 + cycles * period_us * 2 / 1000000 * 8 ))
t0=$(date +%s)
"$HERE/qemu-run.sh" --icount --period-us "$period_us" --timeout "$timeout_s" --log "$log" \
  "${extras[@]+"${extras[@]}"}" "$ROOT/tests/bench/rt-guest.sh" "$cycles" $ct_arg
t1=$(date +%s)

python3 - "$log" "$cycles" "$period_us" "$((t1 - t0))" > "$report" <<'PY'
import re, sys
log, n, period, wall = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
text = open(log, errors="replace").read()
mode = (re.search(r"hap\.mode=(\S+)", text) or [None, "unknown"])[1]
phases = {}
for name, body in re.findall(r"BENCH-BEGIN (\w+)\r?\n(.*?)BENCH-END \1", text, re.S):
    kv, ct = {}, None
    for line in body.splitlines():
        line = line.strip()
        m = re.match(r"cyclictest: T:.*Min:\s*(\d+).*Avg:\s*(\d+)\s+Max:\s*(\d+)", line)
        if m:
            ct = tuple(int(x) for x in m.groups())
            continue
        m = re.match(r"([\w.]+): (.+)", line)
        if m and not line.startswith("cyclictest"):
            kv[m[1]] = m[2]
    phases[name] = (kv, ct)
if not phases:
    sys.exit("bench-rt: no BENCH dumps in " + log)
cols = [p for p in ("idle", "load") if p in phases]
def us(v):  # ns string -> us with 2 decimals
    return f"{int(v) / 1000:.2f}"
def pct(v):
    return ">=1000" if v == "1000" else v
rows = []
def row(label, f):
    vals = []
    for p in cols:
        kv, ct = phases[p]
        try:
            vals.append(f(kv, ct))
        except (KeyError, TypeError, ValueError):
            vals.append("n/a")
    rows.append((label, vals))
row("servo cycles measured", lambda kv, ct: kv["cycles"])
row("guest time for them (ms)", lambda kv, ct: kv["guest_ms"])
row("guest CPU busy (%)", lambda kv, ct: kv["cpu_busy_pct"])
row("guest loadavg 1/5/15 min", lambda kv, ct: kv["loadavg"])
for k, lab in (("wakeup", "SERVO wake-up after CLOCK"), ("exec", "full cycle (SERVO exec)"), ("jitter", "period jitter |dT|")):
    row(f"{lab} min (us)", lambda kv, ct, k=k: us(kv[k + ".min_ns"]))
    row(f"{lab} avg (us)", lambda kv, ct, k=k: us(kv[k + ".avg_ns"]))
    row(f"{lab} p50 (us, 1us bucket)", lambda kv, ct, k=k: pct(kv[k + ".p50_us"]))
    row(f"{lab} p99 (us, 1us bucket)", lambda kv, ct, k=k: pct(kv[k + ".p99_us"]))
    row(f"{lab} p99.9 (us, 1us bucket)", lambda kv, ct, k=k: pct(kv[k + ".p99_9_us"]))
    row(f"{lab} max (us)", lambda kv, ct, k=k: us(kv[k + ".max_ns"]))
    row(f"{lab} overflow (>=1ms)", lambda kv, ct, k=k: kv[k + ".overflow"])
row("jitter signed min/max (us)", lambda kv, ct: us(kv["jitter.signed_min_ns"]) + " / " + us(kv["jitter.signed_max_ns"]))
row("deadline misses", lambda kv, ct: kv["misses"])
row("max consecutive misses", lambda kv, ct: kv["max_consecutive_misses"])
row("ticks not posted", lambda kv, ct: kv["ticks_not_posted"])
row("fail-safe", lambda kv, ct: kv["fail_safe"])
row("cyclictest min/avg/max (us)", lambda kv, ct: "%d / %d / %d" % ct if ct else "not run")
w = max(len(r[0]) for r in rows)
meaning = {"tcg-icount": "guest instruction time, ~1 ns/instruction; costs, not hardware latencies",
           "kvm": "hardware virtualisation: guest wall-clock latencies on this host"}.get(mode, "see Documentation/development.md, Timing modes")
print(f"# hapticctrl bench-rt: mode {mode} ({meaning})")
print(f"# period {period} us, {n} cycles per phase, SERVO SCHED_FIFO 80, cyclictest -m -p 80 -i {period} -l {n} -q next to it")
print(f"# load phase: 3 x sh busy loop, dd if=/dev/zero of=/dev/null bs=1M, fork storm (/bin/true loop), nice 0")
print(f"# wall time of the whole run on this host: {wall} s")
print(f"{'metric [' + mode + ']':<{w}} | " + " | ".join(f"{c:>14}" for c in cols))
print("-" * w + "-+-" + "-+-".join("-" * 14 for _ in cols))
for label, vals in rows:
    print(f"{label:<{w}} | " + " | ".join(f"{v:>14}" for v in vals))
PY
cat "$report"
echo "bench-rt: report $report, guest log $log"
