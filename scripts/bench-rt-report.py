#!/usr/bin/env python3
"""bench-rt.sh's report: parse the guest console of tests/bench/rt-guest.sh,
print the side-by-side table and write the histograms as CSV
(<phase>_<series>.csv, lines "us,count") for `hapctl plot hist`.

    bench-rt-report.py GUEST_LOG OUT_DIR CYCLES PERIOD_US WALL_S
"""
import os
import re
import sys


def quantile(hist, num, den):
    """Smallest bucket v with at least ceil(n*num/den) (>= 1) values <= v
    (hap-core's Histogram::quantile_us, so both columns mean the same)."""
    n = sum(hist.values())
    if n == 0:
        return None
    rank = max(1, -(-n * num // den))
    cum = 0
    for us in sorted(hist):
        cum += hist[us]
        if cum >= rank:
            return us
    return None


def main():
    log, out, n, period, wall = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
    text = open(log, errors="replace").read().replace("\r", "")
    mode = (re.search(r"hap\.mode=(\S+)", text) or [None, "unknown"])[1]
    phases = {}
    for name, body in re.findall(r"BENCH-BEGIN (\w+)\n(.*?)BENCH-END \1", text, re.S):
        kv, ct = {}, {}
        for line in body.splitlines():
            line = line.strip()
            m = re.match(r"cyclictest: # (Min|Avg|Max) Latencies: (\d+)", line)
            if m:
                ct[m[1].lower()] = int(m[2])
                continue
            m = re.match(r"cyclictest: # Histogram Overflows: (\d+)", line)
            if m:
                ct["overflow"] = int(m[1])
                continue
            m = re.match(r"cyclictest: # Total: (\d+)", line)
            if m:
                ct["count"] = int(m[1])
                continue
            m = re.match(r"([\w.]+): (.+)", line)
            if m and not line.startswith("cyclictest"):
                kv[m[1]] = m[2]
        phases[name] = {"kv": kv, "ct": ct, "hist": {}}
    for name, body in re.findall(r"HIST-BEGIN (\w+)\n(.*?)HIST-END \1", text, re.S):
        if name not in phases:
            continue
        hist = {}
        for line in body.splitlines():
            line = line.strip()
            m = re.match(r"(wakeup|exec|jitter)\.hist_us\.(\d+): (\d+)$", line)
            if m:
                hist.setdefault(m[1], {})[int(m[2])] = int(m[3])
                continue
            m = re.match(r"cthist: (\d+) (\d+)$", line)
            if m:
                hist.setdefault("cyclictest", {})[int(m[1])] = int(m[2])
        phases[name]["hist"] = hist
    if not phases:
        sys.exit("bench-rt: no BENCH dumps in " + log + " (did the guest finish? see its tail)")
    os.makedirs(out, exist_ok=True)
    for p, d in phases.items():
        for series, h in d["hist"].items():
            with open(os.path.join(out, f"{p}_{series}.csv"), "w") as f:
                f.write("us,count\n")
                for us in sorted(h):
                    f.write(f"{us},{h[us]}\n")

    cols = [p for p in ("idle", "load") if p in phases]

    def us(v):
        return f"{int(v) / 1000:.2f}"

    def pct(v):
        return ">=1000" if v in ("1000", 1000) else str(v)

    rows = []

    def row(label, f):
        vals = []
        for p in cols:
            try:
                v = f(phases[p])
                vals.append("n/a" if v is None else v)
            except (KeyError, TypeError, ValueError, ZeroDivisionError):
                vals.append("n/a")
        rows.append((label, vals))

    def sep(title):
        rows.append((f"-- {title}", [""] * len(cols)))

    row("servo cycles measured", lambda d: d["kv"]["cycles"])
    row("guest time for them (ms)", lambda d: d["kv"]["guest_ms"])
    row("guest CPU busy (%)", lambda d: d["kv"]["cpu_busy_pct"])
    row("guest loadavg 1/5/15 min", lambda d: d["kv"]["loadavg"])
    for k, lab in (("wakeup", "SERVO wake-up after CLOCK (us)"), ("exec", "full cycle: SERVO exec (us)"),
                   ("jitter", "CLOCK period jitter |dT| (us)")):
        sep(lab)
        row("  min", lambda d, k=k: us(d["kv"][k + ".min_ns"]))
        row("  avg", lambda d, k=k: us(d["kv"][k + ".avg_ns"]))
        row("  p50 / p99 / p99.9 (1 us buckets)", lambda d, k=k: " / ".join(
            pct(d["kv"][k + s]) for s in (".p50_us", ".p99_us", ".p99_9_us")))
        row("  max", lambda d, k=k: us(d["kv"][k + ".max_ns"]))
        row("  overflow (>= 1 ms)", lambda d, k=k: d["kv"][k + ".overflow"])
    row("jitter signed min / max (us)", lambda d: us(d["kv"]["jitter.signed_min_ns"]) + " / " + us(d["kv"]["jitter.signed_max_ns"]))
    sep("cyclictest, same boot, same period, FIFO 80 (us)")
    row("  samples", lambda d: d["ct"]["count"] if d["ct"] else "not run")
    row("  min / avg", lambda d: f'{d["ct"]["min"]} / {d["ct"]["avg"]}')
    row("  p50 / p99 / p99.9 (1 us buckets)", lambda d: " / ".join(
        str(quantile(d["hist"]["cyclictest"], a, b)) for a, b in ((1, 2), (99, 100), (999, 1000))))
    row("  max", lambda d: d["ct"]["max"])
    sep("supervisor")
    row("deadline misses", lambda d: d["kv"]["misses"])
    row("max consecutive misses", lambda d: d["kv"]["max_consecutive_misses"])
    row("ticks not posted", lambda d: d["kv"]["ticks_not_posted"])
    row("degraded cycles", lambda d: d["kv"]["degraded_cycles"])
    row("fail-safe", lambda d: d["kv"]["fail_safe"])
    # Cross-check: the /dev/hap_hist histogram gives the same p99.9 as the stats.
    row("check: hap_hist p99.9 = stats p99.9", lambda d: "yes" if str(quantile(d["hist"]["wakeup"], 999, 1000)) ==
        d["kv"]["wakeup.p99_9_us"] else "NO (%s)" % quantile(d["hist"]["wakeup"], 999, 1000))

    w = max(len(r[0]) for r in rows)
    meaning = {"tcg-icount": "guest instruction time, ~1 ns/instruction: costs, not hardware latencies",
               "kvm": "hardware virtualisation: guest wall-clock latencies on this host",
               "host": "bare metal (bench-rt.sh --host): wall-clock latencies of this machine's kernel"}.get(
        mode, "see Documentation/development.md, Timing modes")
    load = phases.get("load", {}).get("kv", {}).get("load_kind", "n/a")
    print(f"# hapticctrl bench-rt: mode {mode} ({meaning})")
    kernel = re.search(r"HAPTEST-KERNEL (.+)", text)
    print(f"# kernel: {kernel[1].strip() if kernel else 'unknown'}")
    print(f"# period {period} us, {n} cycles per phase, SERVO SCHED_FIFO 80; cyclictest -m -p 80 -i {period} -l {n} -q -h 1000")
    print(f"# load phase: {load}; all SCHED_OTHER nice 0")
    print(f"# wall time of the whole run on this host: {wall} s")
    print(f"{'metric [' + mode + ']':<{w}} | " + " | ".join(f"{c:>16}" for c in cols))
    print("-" * w + "-+-" + "-+-".join("-" * 16 for _ in cols))
    for label, vals in rows:
        print(f"{label:<{w}} | " + " | ".join(f"{v:>16}" for v in vals))


if __name__ == "__main__":
    main()
