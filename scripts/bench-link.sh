#!/usr/bin/env bash
# Link benchmark: the test client on the host <-> the controller in
# ONE QEMU guest (module + proto_interface started by the launch script, as
# in tests/e2e/link.sh: tests/guest/serve.sh, the user walking the handle
# with tests/data/walk.eff), for N client cycles at a given request interval.
#
#   scripts/bench-link.sh [--samples N] [--interval-us U] [--period-us P]
#                         [--port HOSTPORT] [--out DIR] [--long] [--no-plot]
#
#   --samples N       client cycles = VprStream requests (default 100000)
#   --long            N = 10^6 (~17 min of requests at 1 kHz, plus boot)
#   --interval-us U   client request interval (default 1000 = 1 kHz; the
#                     spec's rate is 3000 = 1 sample / 3 ms)
#   --period-us P     servo period in the guest (default 1000)
#   --port HOSTPORT   host UDP port forwarded to the guest's 5000 (default 47310)
#   --out DIR         results (default build/bench/link-<UTC stamp>)
#   --max-seconds T   stop the client after T s of real time even if fewer
#                     than N requests were sent (the report says so)
#   --no-plot         do not render rtt_hist/rate plots with hapctl
#   --insecure        unauthenticated protocol v1 (bridge --insecure, client
#                     without key), to compare with the default v2 (a key in
#                     build/hap-test.key, every frame authenticated)
#   --sleep-off       run the guest under --icount (tcg-icount, sleep=off):
#                     host scheduling cannot make the servo miss, but the
#                     guest runs faster than real time while it idles, so
#                     rates and RTTs are not timing figures; loss, counters
#                     and the absence of misses over N samples are
#   --icount-shift S  guest ns per instruction = 2^S (default 2, see below)
#   --nice N          run QEMU and the client at nice N (e.g. -10, needs root;
#                     default 0). On a shared, loaded host, icount-sleep guest
#                     time jumps whenever QEMU waits for a CPU while the guest
#                     idles, which shows as deadline misses; the report gives
#                     the nice value and the host load average.
#
# Mode: tcg-icount-sleep (qemu-run.sh --icount-sleep: guest busy time is
# counted in instructions, idle time follows the host clock; the only TCG
# mode where a host<->guest UDP link works and a 1 ms servo holds). Guest
# time then runs at ~1/3 of real time while the guest is busy, so answers
# per REAL second are ~1/3 of the servo rate; the report gives both the real
# and the guest-time rate. Where qemu-run.sh finds a working KVM it uses it
# and the report names that mode.
#
# icount shift: with shift 0 (1 ns per guest instruction, qemu-run.sh's
# default) a shared host runs the guest at 0.07-0.25 of real time, so a
# client pacing itself in REAL time floods the guest in GUEST time (10+
# datagrams per 1 ms servo period): misses and a fail-safe within seconds.
# Shift 2 (4 ns per instruction, a 250 MIPS virtual CPU) keeps guest time at
# about half of real time here. A servo cycle then costs ~256 us of guest
# time instead of ~64: this mode measures the link, not the cycle's latency
# (scripts/bench-rt.sh does that, under tcg-icount).
#
# Output in DIR: report.txt (the figures), client/summary.txt (client's
# key: value summary), client/rtt_hist.csv (value_us,count: 1 us buckets),
# client/rate.csv (t_s,answers_per_s,... one row per real second),
# hap_stats.txt and proto_interface.txt (module and bridge counters at the
# end), guest.log, and plots (rtt_hist.svg, rate.svg) when hapctl has them.
# Figures are printed, never asserted (timing is not a test).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
ROOT=$HAP_ROOT

proto=v2; samples=100000; interval_us=1000; period_us=1000; port=47310; out=""; plot=1; nice_n=0; shift_s=2; max_seconds=0; qmode=--icount-sleep
while [ $# -gt 0 ]; do
  case "$1" in
    --samples) [ $# -ge 2 ] || die "--samples needs a value"; hap_uint "$1" "$2"; samples=$2; shift ;;
    --long) samples=1000000 ;;
    --interval-us) [ $# -ge 2 ] || die "--interval-us needs a value"; hap_uint "$1" "$2"; interval_us=$2; shift ;;
    --period-us) [ $# -ge 2 ] || die "--period-us needs a value"; hap_uint "$1" "$2"; period_us=$2; shift ;;
    --port) [ $# -ge 2 ] || die "--port needs a value"; hap_uint "$1" "$2"; port=$2; shift ;;
    --out) [ $# -ge 2 ] || die "--out needs a value"; out=$2; shift ;;
    --no-plot) plot=0 ;;
    --insecure) proto=v1 ;;
    --sleep-off) qmode=--icount ;;
    --max-seconds) [ $# -ge 2 ] || die "--max-seconds needs a value"; hap_uint "$1" "$2"; max_seconds=$2; shift ;;
    --icount-shift) [ $# -ge 2 ] || die "--icount-shift needs a value"; hap_uint "$1" "$2"; shift_s=$2; shift ;;
    --nice) [ $# -ge 2 ] || die "--nice needs a value"; [[ "$2" =~ ^-?[0-9]+$ ]] || die "--nice needs an integer, got '$2'"; nice_n=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
[ "$samples" -ge 1 ] || die "--samples must be >= 1"
[ "$interval_us" -ge 200 ] && [ "$interval_us" -le 100000 ] || die "--interval-us must be in 200..100000"
[ "$port" -ge 1024 ] && [ "$port" -le 65535 ] || die "--port must be in 1024..65535"
stamp=$(date -u +%Y%m%dT%H%M%SZ)
out=${out:-$ROOT/build/bench/link-$stamp}
mkdir -p "$out/client"

# Builds: the module, the static guest tools, the host client.
[ -f "$ROOT/build/base/module/hapticctrl.ko" ] || make -C "$ROOT" >&2
bash "$HERE/build-userspace-static.sh" >&2
(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo) || die "cannot build virtuose_demo"
demo="$ROOT/userspace/target/release/virtuose_demo"
python3 -c "import socket,sys; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(('127.0.0.1', int(sys.argv[1])))" "$port" 2>/dev/null \
  || die "host UDP port $port is busy (use --port)"

# The guest serves until the client has closed its session; the limit only
# guards against a hang: the requests' real time, twice, plus boot.
max_s=$(( samples * interval_us / 1000000 * 2 + 180 ))
t_boot=$(date +%s)
load0=$(cut -d' ' -f1-3 /proc/loadavg)
if [ "$proto" = v2 ]; then
  key=$(hap_keyfile "$ROOT/build/hap-test.key"); bridge_auth=(--key "$key"); client_auth=(--key "$key")
else
  bridge_auth=(--insecure-bridge); client_auth=()
fi
read -r qpid qlog < <(HAP_ICOUNT_SHIFT=$shift_s nice -n "$nice_n" bash "$HERE/qemu-run.sh" --background "$qmode" --udp "$port:5000" \
  --log "$out/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" "${bridge_auth[@]}" \
  "$ROOT/tests/guest/serve.sh" "$period_us" "$max_s")
trap 'kill "$qpid" 2>/dev/null || true' EXIT
for _ in $(seq 1200); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog" >&2; die "the guest did not get ready (log: $qlog)"; }
t_ready=$(date +%s)
log "guest ready after $((t_ready - t_boot)) s; client: $samples requests every $interval_us us -> 127.0.0.1:$port"

nice -n "$nice_n" "$demo" --server "127.0.0.1#$port" "${client_auth[@]+"${client_auth[@]}"}" --headless --samples "$samples" --duration "$max_seconds" --interval-us "$interval_us" \
  --timeout-ms 300 --bench --results "$out/client" > "$out/client.txt" 2>&1 &
dpid=$!
trap 'kill "$dpid" "$qpid" 2>/dev/null || true' EXIT
# If the guest ends first (a fail-safe closes the session, and serve.sh then
# stops), stop the client: it writes its summary on SIGTERM.
while kill -0 "$dpid" 2>/dev/null; do
  if ! kill -0 "$qpid" 2>/dev/null; then
    log "the guest ended before the client (fail-safe?): stopping the client"
    kill -TERM "$dpid" 2>/dev/null || true
    break
  fi
  sleep 1
done
set +e
wait "$dpid"
crc=$?
set -e
t_client=$(date +%s)
for _ in $(seq 1800); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
kill "$qpid" 2>/dev/null || true
trap - EXIT
t_end=$(date +%s)
load1=$(cut -d' ' -f1-3 /proc/loadavg)
[ "$crc" = 0 ] || { tail -5 "$out/client.txt" >&2; log "the client failed (exit $crc); partial report follows"; }

between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d '\r' | grep -v -- "$1-" || true; }
between HAP-STATS > "$out/hap_stats.txt"
between HAP-PROTO > "$out/proto_interface.txt"

python3 - "$out" "$samples" "$interval_us" "$period_us" "$crc" \
  "$((t_ready - t_boot))" "$((t_client - t_ready))" "$((t_end - t_boot))" "$load0" "$load1" "$(nproc)" "$nice_n" "$shift_s" "$proto" > "$out/report.txt" <<'PY'
import re, sys
out, samples, interval, period, crc, boot_s, client_s, wall_s, load0, load1, ncpu, nice_n, shift_s, proto = sys.argv[1:]
def kv(path):
    d = {}
    try:
        for line in open(path, errors="replace"):
            m = re.match(r"^([\w.]+): *(\S+)", line)
            if m and m[1] not in d:
                d[m[1]] = m[2]
    except FileNotFoundError:
        pass
    return d
c, m, b = kv(f"{out}/client/summary.txt"), kv(f"{out}/hap_stats.txt"), kv(f"{out}/proto_interface.txt")
log = open(f"{out}/guest.log", errors="replace").read()
mode = (re.search(r"hap\.mode=(\S+)", log) or [None, "unknown"])[1]
if mode == "tcg-icount-sleep":
    mode += f" shift={shift_s}"
mode += ", protocol v2 (authenticated)" if proto == "v2" else ", protocol v1 (unauthenticated, --insecure)"
problems = re.findall(r".*(?:Kernel panic|Oops|WARNING:|BUG:|Call Trace|rust_panic|panicked at).*", log)
g = lambda d, k: d.get(k, "?")
def f(x, fmt="{:.1f}"):
    try:
        return fmt.format(float(x))
    except (TypeError, ValueError):
        return "?"
def i(d, k):
    try:
        return int(d.get(k, ""))
    except ValueError:
        return None
vpr_sent, vpr_mod = i(c, "vpr_sent"), i(m, "vpr_frames")
req_lost = vpr_sent - vpr_mod if vpr_sent is not None and vpr_mod is not None else "?"
p = print
p(f"# hapticctrl link benchmark, mode {mode}")
p(f"client: {samples} requests (VprStream) every {interval} us; servo period {period} us; client exit {crc}")
p(f"wall: boot {boot_s} s, client {client_s} s, total {wall_s} s; host load average {load0} at the start, {load1} at the end ({ncpu} CPUs, shared); QEMU and client at nice {nice_n}")
p("")
p(f"| figure [{mode}] | value |")
p("|---|---|")
p(f"| requests sent (VprStream) | {g(c, 'vpr_sent')} at {f(g(c, 'request_rate_hz'))} /s real |")
p(f"| answers received | {g(c, 'answers')} ({g(c, 'bench_answers')} during the benchmark) |")
p(f"| answer rate, real time | {f(g(c, 'sample_rate_hz'))} /s |")
p(f"| guest time / real time | {f(g(c, 'guest_time_ratio'), '{:.3f}')} ({f(g(c, 'guest_s'))} guest s) |")
p(f"| answer rate, guest time | {f(g(c, 'answer_rate_guest_hz'))} /s (servo: {1e6 / int(period):.0f} /s) |")
p(f"| answer loss (gaps in the controller's sequence numbers) | {g(c, 'lost')} of {g(c, 'answers')} + {g(c, 'lost')} = {f(float(g(c, 'loss_ratio')) * 100 if g(c, 'loss_ratio') != '?' else '?', '{:.4f}')} % |")
p(f"| duplicates / stale / undecodable answers | {g(c, 'duplicates')} / {g(c, 'stale')} / {g(c, 'decode_errors')} |")
p(f"| requests lost on the way (client VprStream sent - module vpr_frames) | {req_lost} |")
p(f"| requests echoed by an answer (RTT samples) | {g(c, 'rtt_samples')} (not echoed: {g(c, 'requests_not_echoed')}, superseded by a newer one before a servo cycle read it, or lost) |")
p(f"| RTT min / p50 / p99 / p99.9 / max (us, real time) | {g(c, 'rtt_us_min')} / {g(c, 'rtt_us_p50')} / {g(c, 'rtt_us_p99')} / {g(c, 'rtt_us_p99_9')} / {g(c, 'rtt_us_max')} |")
p(f"| RTT mean (us) | {g(c, 'rtt_us_mean')} |")
p(f"| coupling error mean / max (m) | {g(c, 'coupling_error_mean_m')} / {g(c, 'coupling_error_max_m')} |")
p(f"| bridge: received / forwarded / rejected / write errors | {g(b, 'received')} / {g(b, 'forwarded')} / {g(b, 'rejected')} / {g(b, 'write_errors')} |")
p(f"| bridge: answers read / sent / no client / send errors | {g(b, 'answers')} / {g(b, 'sent')} / {g(b, 'answers_no_client')} / {g(b, 'send_errors')} |")
rej = {k: v for k, v in m.items() if k.startswith("rejected.") and v != "0"}
p(f"| module: frames in / rejected (by reason) | {g(m, 'frames_in')} / {g(m, 'frames_rejected')} decode + {i(m, 'rejected.no_session') or 0} no_session + {i(m, 'rejected.stale_seq') or 0} stale + {i(m, 'rejected.not_a_request') or 0} not_a_request {rej or ''} |")
p(f"| module: answers sent / dropped (rtf_out full) / skipped (VPr latch busy) | {g(m, 'answers_sent')} / {g(m, 'answers_dropped')} / {g(m, 'answers_skipped_latch_busy')} |")
p(f"| module: servo cycles / deadline misses / max consecutive / fail-safe | {g(m, 'cycles')} / {g(m, 'misses')} / {g(m, 'max_consecutive_misses')} / {g(m, 'fail_safe')} |")
p(f"| module: VPr extrapolated cycles / degraded cycles | {g(m, 'vpr_extrapolated')} / {g(m, 'degraded_cycles')} |")
p(f"| kernel warnings in the guest log | {len(problems)} |")
# The launch script's stop (after the statistics) is a fail-safe too: not counted.
fs = [x for x in re.findall(r"hapticctrl: fail-safe \((\w+)\): start \(tick (\d+)", log) if x[0] != "stop_requested"]
if fs:
    p("")
    p(f"**FAIL-SAFE during the run**: cause {fs[0][0]} at servo tick {fs[0][1]} (the protocol was closed there;")
    p("figures after it are not a link measurement). Under tcg-icount-sleep a host that deschedules QEMU")
    p("while the guest idles makes guest time jump (sleep=on follows the host clock when idle): see the load average.")
p("")
p("Definitions: a *sample* is one client cycle (one VprStream request). Answer")
p("loss = controller frames (answers and answer_twist share one sequence")
p("counter) missing between consecutive accepted ones, over answers received +")
p("missing. RTT = time from sending a VprStream to receiving the first answer")
p("whose vpr_seq echoes it (real time on the host; includes the wait for the")
p("next servo cycle). Guest time = servo cycles x period (cycle counter in the")
p("answers).")
for line in problems[:10]:
    p(f"guest: {line}")
PY

if [ "$plot" = 1 ]; then
  hapctl="$ROOT/userspace/target/release/hapctl"
  (cd "$ROOT/userspace" && cargo build --release --quiet -p hapctl) >&2 || true
  if [ -x "$hapctl" ] && "$hapctl" plot-link --help >/dev/null 2>&1; then
    mode=$(sed -n 's/^# hapticctrl link benchmark, mode //p' "$out/report.txt")
    "$hapctl" plot-link --dir "$out/client" --out "$out" \
      --title "($samples requests / ${interval_us} us, $mode)" >&2 || log "plotting failed (figures above stand)"
  fi
fi
cat "$out/report.txt"
log "results in $out"
