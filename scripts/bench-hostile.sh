#!/usr/bin/env bash
# Hostile-input campaign: hostile datagrams at the bridge WHILE a
# legitimate client servos, in ONE QEMU guest (tcg-icount-sleep by default,
# as the link tests; --sleep-off for tcg-icount, where a loaded host cannot
# make the servo miss: the reference run, Documentation/reliability.md). Two
# layers, every frame built by `hapdev hostile` with hap-core
# (encoder, CRC-32C, frame table) and tallied by the counter it must land in:
#
#  net  N datagrams from the host at the bridge (proto_interface) from a
#       stray source port: random bytes, truncated, oversized, bad CRC,
#       valid CRC with a wrong session, replayed sequence numbers, NaN/Inf
#       floats (valid CRC), bad values (out of range, bad enum/bool, reserved
#       flag bits), controller-only frame types, a second OpenSession, bit
#       flips, wrong lengths. Must be counted by the bridge's reject counters
#       (oversize / undersize / malformed / stray source) and never forwarded.
#  dev  M frames written in the guest straight into /dev/hap_rtf_in next to
#       the live session (what a broken bridge could write): must be counted
#       by the module (rtf_in.bad_length, rejected.<decode reason>,
#       rejected.no_session / stale_seq / not_a_request) and change nothing.
#
#   scripts/bench-hostile.sh [--count N] [--dev-count M] [--rate HZ]
#                            [--port HOSTPORT] [--out DIR]
#
#   --count N       hostile datagrams at the bridge (default 100000)
#   --dev-count M   hostile frames into rtf_in in the guest (default 20000;
#                   0 to skip)
#   --client-interval-us U  the legitimate client's request interval
#                   (default 3000: the spec's 1 sample / 3 ms; 1000 floods a
#                   guest slowed down by a loaded host, see bench-link.sh)
#   --rate HZ       datagrams per second of real time (default 1000)
#   --period-us P   servo period in the guest (default 1000; a longer one
#                   gives an emulated guest slowed by a loaded host the slack
#                   to hold its deadlines, so the counters can be checked)
#   --sleep-off     run the guest under --icount (sleep=off: guest time is
#                   the instruction count only, so host scheduling cannot
#                   make the servo miss; the guest then runs faster than real
#                   time while it idles, so the link's timing means nothing,
#                   but every datagram still crosses it)
#   --report DIR    only (re)write the report of an earlier run's DIR
#   --port P        host UDP port forwarded to the guest's 5000 (default 47320)
#   --out DIR       results (default build/bench/hostile-<UTC stamp>)
#   --icount-shift S  guest ns per instruction = 2^S (default 2; see
#                   scripts/bench-link.sh --help)
#   --nice N        run QEMU and the client at nice N (e.g. -10, needs root;
#                   default 0): see scripts/bench-link.sh --help
#
# It ASSERTS correctness (a campaign may; timing is never asserted): no
# oops/WARN/BUG in the guest log, no deadline miss and no fail-safe, every
# hostile datagram the bridge received and every device frame in the counter
# it belongs to (exact counts; datagrams lost on the way, before the guest's
# UDP stack, are reported with the guest's UDP counters), the
# module saw only the legitimate frames plus the device-level ones, one
# session all along, and the legitimate client still coupled. Prints
# "N passed, N failed"; exit status 0 iff all passed.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
ROOT=$HAP_ROOT

report_only=""; count=100000; dev_count=20000; rate=1000; port=47320; out=""; period_us=1000; nice_n=0; shift_s=2; client_iv=3000; qmode=--icount-sleep
while [ $# -gt 0 ]; do
  case "$1" in
    --count) [ $# -ge 2 ] || die "--count needs a value"; hap_uint "$1" "$2"; count=$2; shift ;;
    --dev-count) [ $# -ge 2 ] || die "--dev-count needs a value"; hap_uint "$1" "$2"; dev_count=$2; shift ;;
    --client-interval-us) [ $# -ge 2 ] || die "--client-interval-us needs a value"; hap_uint "$1" "$2"; client_iv=$2; shift ;;
    --rate) [ $# -ge 2 ] || die "--rate needs a value"; hap_uint "$1" "$2"; rate=$2; shift ;;
    --period-us) [ $# -ge 2 ] || die "--period-us needs a value"; hap_uint "$1" "$2"; period_us=$2; shift ;;
    --sleep-off) qmode=--icount ;;
    --report) [ $# -ge 2 ] || die "--report needs a value"; report_only=$2; shift ;;
    --port) [ $# -ge 2 ] || die "--port needs a value"; hap_uint "$1" "$2"; port=$2; shift ;;
    --out) [ $# -ge 2 ] || die "--out needs a value"; out=$2; shift ;;
    --icount-shift) [ $# -ge 2 ] || die "--icount-shift needs a value"; hap_uint "$1" "$2"; shift_s=$2; shift ;;
    --nice) [ $# -ge 2 ] || die "--nice needs a value"; [[ "$2" =~ ^-?[0-9]+$ ]] || die "--nice needs an integer, got '$2'"; nice_n=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
[ "$count" -ge 1 ] || die "--count must be >= 1"
[ "$rate" -ge 1 ] && [ "$rate" -le 20000 ] || die "--rate must be in 1..20000"
[ "$port" -ge 1024 ] && [ "$port" -le 65535 ] || die "--port must be in 1024..65535"
report() { # DIR: the report from the saved run parameters
  local out=$1
  [ -f "$out/params" ] || die "$out/params: not a bench-hostile results directory"
  # shellcheck disable=SC2046
  set -- $(cat "$out/params")
  python3 - "$out" "$@" <<'PY' | tee "$out/report.txt"
import re, sys
out, hrc, crc, count, dev_count, rate, boot_s, client_s, wall_s, load0, load1, nice_n, shift_s = sys.argv[1:]
count, dev_count = int(count), int(dev_count)
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
def n(d, k, default=None):
    try:
        return int(d[k])
    except (KeyError, ValueError):
        return default
net, dev = kv(f"{out}/hostile_net.txt"), kv(f"{out}/hostile_dev.txt")
m, m0, b, c = kv(f"{out}/hap_stats.txt"), kv(f"{out}/hap_stats_before.txt"), kv(f"{out}/proto_interface.txt"), kv(f"{out}/client/summary.txt")
log = open(f"{out}/guest.log", errors="replace").read()
mode = (re.search(r"hap\.mode=(\S+)", log) or [None, "unknown"])[1]
if mode == "tcg-icount-sleep":
    mode += f" shift={shift_s}"
passed = failed = 0
def check(desc, ok, detail=""):
    global passed, failed
    if ok:
        passed += 1; print(f"ok - {desc}{' (' + detail + ')' if detail else ''}")
    else:
        failed += 1; print(f"not ok - {desc}{' (' + detail + ')' if detail else ''}")
print(f"# hapticctrl hostile-input campaign, mode {mode}")
period = re.search(r"HAP-READY period_us=(\d+)", log)
print(f"# servo period {period[1] if period else '?'} us")
print(f"# wall: boot {boot_s} s, client + campaign {client_s} s, total {wall_s} s; host load average {load0} -> {load1}; QEMU and client at nice {nice_n}")
print(f"# net: {n(net, 'sent')} datagrams in {net.get('seconds', '?')} s; dev: {n(dev, 'sent')} frames in {dev.get('seconds', '?')} s (guest)")
for k, v in sorted(net.items()):
    if k.startswith(("kind.", "expect.")):
        print(f"#   net {k}: {v}")
for k, v in sorted(dev.items()):
    if k.startswith(("kind.", "expect.")) or k in ("retries_full", "refused"):
        print(f"#   dev {k}: {v}")
problems = re.findall(r".*(?:Kernel panic|Oops|WARNING:|BUG:|Call Trace|possible (?:circular|recursive) locking|sleeping function called|general protection fault|rust_panic|panicked at).*", log)
check("no oops / WARN / BUG / panic in the guest log", not problems, "; ".join(problems[:3]))
check("the host campaign ran", hrc == "0" and n(net, "sent") == count, f"exit {hrc}, sent {n(net, 'sent')} of {count}")
if dev_count:
    check("the device campaign ran", n(dev, "sent") == dev_count, f"sent {n(dev, 'sent')} of {dev_count}")
# Bridge: every hostile datagram in its reject counter, exactly. The
# legitimate client's datagrams are all valid and from the pinned source,
# so any other reject would be a hostile datagram too.
# Datagrams can be lost between the host and the bridge (QEMU's user-mode
# network, the guest's socket buffer: see guest_udp.txt); those never reach
# a counter. So: nothing the bridge received goes uncounted, no class gets
# more than was sent of it, and the transit loss is reported.
check("bridge: every datagram received is counted (received == forwarded + rejected + write errors)",
      n(b, "received") == (n(b, "forwarded") or 0) + (n(b, "rejected") or 0) + (n(b, "write_errors") or 0),
      f"{n(b, 'received')} vs {n(b, 'forwarded')} + {n(b, 'rejected')} + {n(b, 'write_errors')}")
lost_net = 0
for r in ("rejected_oversize", "rejected_undersize", "rejected_malformed", "rejected_stray_source"):
    want, got = n(net, f"expect.{r}", 0), n(b, r)
    lost_net += want - (got or 0)
    check(f"bridge {r} <= hostile datagrams sent of that class", got is not None and got <= want,
          f"{got} of {want}, {100.0 * (want - (got or 0)) / max(want, 1):.2f} % not received")
udp = {}
try:
    lines = [l.split() for l in open(f"{out}/guest_udp.txt") if l.startswith("Udp:")]
    if len(lines) >= 2:
        udp = dict(zip(lines[0][1:], lines[1][1:]))
except FileNotFoundError:
    pass
print(f"# transit: {lost_net} of {count} hostile datagrams ({100.0 * lost_net / count:.3f} %) never reached the bridge; "
      f"guest UDP InDatagrams {udp.get('InDatagrams', '?')}, RcvbufErrors {udp.get('RcvbufErrors', '?')}, InErrors {udp.get('InErrors', '?')}")
# The only other reject: the client's own CloseSession retransmitted after
# the first one closed the session (its ack was slow): rejected_no_session,
# at most the client's 4 attempts.
late = n(b, "rejected_no_session", 0)
check("bridge rejected_no_session <= 3 (the client's late CloseSession retransmissions only)", late <= 3, str(late))
check("bridge rejected total == hostile datagrams received + those", n(b, "rejected") == count - lost_net + late,
      f"{n(b, 'rejected')} vs {count} - {lost_net} + {late}")
check("bridge: no write error", n(b, "write_errors") == 0, str(n(b, "write_errors")))
# That no hostile datagram was forwarded is shown by the module: its reject
# counters hold exactly the device-level tallies (a forwarded wrong-session,
# NaN, replayed... frame would add to one of them), and below.
# Module: the device-level frames in their counters, exactly.
names = set(k for k in m if k.startswith("rejected.") or k == "rtf_in.bad_length")
for k in sorted(names | {k[len("expect."):] for k in dev if k.startswith("expect.")}):
    want = n(dev, f"expect.{k}", 0)
    got = n(m, k)
    check(f"module {k} == device frames sent of that class", got == want, f"{got} vs {want}")
check("module rtf_in.full == 0 (nothing lost for lack of room)", n(m, "rtf_in.full") == 0, str(n(m, "rtf_in.full")))
# Every frame that reached PROTO_IN is accounted: accepted + rejected =
# forwarded by the bridge + device frames that passed the length check.
dev_in = (n(dev, "sent") or 0) - n(dev, "expect.rtf_in.bad_length", 0)
proto_rej = n(m, "frames_rejected", 0) + sum(n(m, f"rejected.{r}", 0) for r in ("no_session", "stale_seq", "not_a_request"))
check("module frames in + rejected == bridge forwarded + device frames of valid length",
      n(m, "frames_in", 0) + proto_rej == (n(b, "forwarded") or 0) + dev_in,
      f"{n(m, 'frames_in')} + {proto_rej} vs {n(b, 'forwarded')} + {dev_in}")
check("module: one session opened, none other (bridge too)", n(m, "sessions_opened") == 1 and n(b, "sessions_opened") == 1,
      f"module {n(m, 'sessions_opened')}, bridge {n(b, 'sessions_opened')}")
check("module: no deadline miss", n(m, "misses") == 0, f"misses {n(m, 'misses')}, max consecutive {n(m, 'max_consecutive_misses')}, degraded cycles {n(m, 'degraded_cycles')}")
check("module: no fail-safe", n(m, "fail_safe") == 0, str(n(m, "fail_safe")))
# The legitimate client: ran to the end, coupled, no loss beyond the spec.
def f(d, k):
    try:
        return float(d[k])
    except (KeyError, ValueError):
        return float("nan")
check("the legitimate client ran to the end", crc == "0", f"exit {crc}")
check("legitimate client: answers >= 1000", (n(c, "answers") or 0) >= 1000, str(n(c, "answers")))
check("legitimate client: answer loss < 10 % (spec)", f(c, "loss_ratio") < 0.1, f"{f(c, 'loss_ratio') * 100:.4f} %")
check("legitimate client: still coupled (mean coupling error <= 5 mm)", f(c, "coupling_error_mean_m") <= 0.005, f"{c.get('coupling_error_mean_m')} m")
check("legitimate client: the coupled sphere followed the handle (>= 2 cm travel)", f(c, "coupled_travel_m") >= 0.02, f"{c.get('coupled_travel_m')} m")
check("guest side passed (launch script, session kept, clean stop)", "HAPTEST-RESULT rc=0" in log,
      "; ".join(re.findall(r"not ok.*", log)[:3]))
print(f"# FIGURES [{mode}]: client answers {c.get('answers')}, loss {f(c, 'loss_ratio') * 100:.4f} %, rate {c.get('sample_rate_hz')} /s real, "
      f"RTT p50/p99/max {c.get('rtt_us_p50')}/{c.get('rtt_us_p99')}/{c.get('rtt_us_max')} us; module cycles {m.get('cycles')}, "
      f"misses {m.get('misses')}, replies (errors to no_session) {m.get('replies')}, answers dropped {m.get('answers_dropped')}")
print(f"hostile: {passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
PY
}
if [ -n "$report_only" ]; then
  report "$report_only"
  exit $?
fi
stamp=$(date -u +%Y%m%dT%H%M%SZ)
out=${out:-$ROOT/build/bench/hostile-$stamp}
mkdir -p "$out/client"

[ -f "$ROOT/build/base/module/hapticctrl.ko" ] || make -C "$ROOT" >&2
bash "$HERE/build-userspace-static.sh" >&2
(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo -p hapdev) || die "cannot build the host tools"
demo="$ROOT/userspace/target/release/virtuose_demo"
hapdev="$ROOT/userspace/target/release/hapdev"
python3 -c "import socket,sys; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(('127.0.0.1', int(sys.argv[1])))" "$port" 2>/dev/null \
  || die "host UDP port $port is busy (use --port)"

net_s=$(( count / rate + 1 ))
dev_iv=2000                                    # guest µs between device frames
client_s=$(( net_s * 3 + 60 ))                 # only bounds the guest; the client is stopped after the net campaign
max_s=$(( client_s * 4 + dev_count * dev_iv / 1000000 * 4 + 300 ))
t_boot=$(date +%s)
load0=$(cut -d' ' -f1-3 /proc/loadavg | tr ' ' ,)
# Unauthenticated v1 on purpose: this campaign aims valid-looking v1 frames
# at the module's own checks through the bridge (tests/e2e/auth.sh covers the
# authenticated bridge).
read -r qpid qlog < <(HAP_ICOUNT_SHIFT=$shift_s nice -n "$nice_n" bash "$HERE/qemu-run.sh" --background "$qmode" --udp "$port:5000" --insecure-bridge \
  --log "$out/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$ROOT/tests/guest/hostile.sh" "$period_us" "$max_s" "$dev_count" "$dev_iv")
trap 'kill "$qpid" 2>/dev/null || true' EXIT
for _ in $(seq 1200); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog" >&2; die "the guest did not get ready (log: $qlog)"; }
t_ready=$(date +%s)
log "guest ready after $((t_ready - t_boot)) s; client ${client_s} s every ${client_iv} us, $count hostile datagrams at $rate/s, $dev_count device frames"

nice -n "$nice_n" "$demo" --server "127.0.0.1#$port" --headless --duration 0 --interval-us "$client_iv" --timeout-ms 300 --bench \
  --results "$out/client" > "$out/client.txt" 2>&1 &
dpid=$!
trap 'kill "$dpid" "$qpid" 2>/dev/null || true' EXIT
sleep 5
set +e
"$hapdev" hostile net --to "127.0.0.1:$port" --count "$count" --interval-us $(( 1000000 / rate )) > "$out/hostile_net.txt" 2>&1
hrc=$?
sleep 5                       # the last hostile datagrams reach the bridge
kill -TERM "$dpid" 2>/dev/null  # the client closes its session and writes its summary
wait "$dpid"
crc=$?
set -e
t_client=$(date +%s)
for _ in $(seq 3000); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
kill "$qpid" 2>/dev/null || true
trap - EXIT
t_end=$(date +%s)
load1=$(cut -d' ' -f1-3 /proc/loadavg | tr ' ' ,)

between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d '\r' | grep -v -- "$1-" || true; }
between HAP-STATS0 > "$out/hap_stats_before.txt"
between HAP-STATS > "$out/hap_stats.txt"
between HAP-PROTO > "$out/proto_interface.txt"
between HAP-HOSTILE-DEV > "$out/hostile_dev.txt"
between HAP-UDP > "$out/guest_udp.txt"

echo "$hrc" "$crc" "$count" "$dev_count" "$rate" "$((t_ready - t_boot))" "$((t_client - t_ready))" \
  "$((t_end - t_boot))" "$load0" "$load1" "$nice_n" "$shift_s" > "$out/params"
report "$out"
