#!/usr/bin/env bash
# Host <-> guest end-to-end (plain TCG: the guest clock follows the host's,
# which a UDP link needs). The test client (virtuose_demo, headless) on the
# host couples to the simulated arm in the guest through proto_interface for
# DURATION seconds at 1 kHz; meanwhile a second client from another source
# port must be refused and 10^4 hostile datagrams must be counted and change
# nothing. Prints every figure, then "N passed, N failed".
# Prints the guest's kernel (`uname -rv`).
#   tests/e2e/link.sh [--stock] [--duration S] [--period-us N] [--results DIR]
# --stock: Debian's stock 7.3 rt-amd64 kernel with the module built against
# its headers (make STOCK=1); default: the project's test kernel.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
duration=15; period_us=1000; results="$ROOT/build/e2e"; kflag=""
while [ $# -gt 0 ]; do
  case "$1" in
    --duration) duration=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    --results) results=$2; shift ;;
    --stock) kflag=--stock ;;
    *) die "unknown argument $1" ;;
  esac
  shift
done
mkdir -p "$results"; rm -f "$results"/*
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
check_num() { # desc value op limit
  if awk -v v="$2" -v l="$4" "BEGIN { exit !(v $3 l) }"; then ok "$1 ($2 $3 $4)"; else nok "$1 (got '$2', want $3 $4)"; fi
}
demo="$ROOT/userspace/target/release/virtuose_demo"
[ -x "$demo" ] || (cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo) || die "cannot build virtuose_demo"

port=$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
# Authenticated (protocol v2): the bridge gets the key, so does the test
# client; the second client has none. HAP_E2E_INSECURE=1: the bridge and the
# client speak the unauthenticated v1 (the bridge's --insecure).
key=$(hap_keyfile "$ROOT/build/hap-test.key")
insecure=${HAP_E2E_INSECURE:-0}
if [ "$insecure" = 1 ]; then bridge_auth=(--insecure-bridge); client_key=(); else bridge_auth=(--key "$key"); client_key=(--key "$key"); fi
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background $kflag ${HAP_E2E_QEMU:---icount-sleep} --udp "$port:5000" "${bridge_auth[@]}" \
  --log "$results/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$ROOT/tests/guest/serve.sh" "$period_us" $((duration + 60)))
trap 'kill $qpid 2>/dev/null' EXIT
for _ in $(seq 600); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; die "the guest did not get ready"; }
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# guest ready (plain TCG, servo period ${period_us} us); UDP 127.0.0.1:$port -> guest:5000"

if [ "${HAP_E2E_NO_HOSTILE:-0}" = 1 ]; then true & else
python3 "$ROOT/tests/e2e/udp_garbage.py" 127.0.0.1 "$port" 10000 3 > "$results/garbage.txt" 2>&1 &
fi
gpid=$!
( sleep 4; HAP_KEY_FILE= timeout 30 "$demo" --server "127.0.0.1#$port" --headless --duration 2 --timeout-ms 300 > "$results/second_client.txt" 2>&1; echo $? > "$results/second_client.rc" ) &
spid=$!
"$demo" --server "127.0.0.1#$port" "${client_key[@]}" --headless --duration "$duration" --results "$results" > "$results/client.txt" 2>&1
crc=$?
wait "$gpid" "$spid"
for _ in $(seq 1200); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
kill "$qpid" 2>/dev/null
trap - EXIT

sed 's/^/# client: /' "$results/client.txt" | grep -E 'summary|sample_rate|loss|rtt|coupling|travel|answers|lost|error' | head -20
sed 's/^/# /' "$results/garbage.txt"
sv() { sed -n "s/^$1: //p" "$results/summary.txt" 2>/dev/null | head -1; }
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt"
between HAP-PROTO > "$results/proto_interface.txt"
between HAP-SIMLOG | sed -E 's/\[ *[0-9]+\.[0-9]+\] .*$//' | grep -E "^[A-Za-z0-9+/=]+$" | base64 -d 2>/dev/null | gzip -dc > "$results/simlog.bin" 2>/dev/null
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }

[ "$crc" = 0 ] && ok "the test client ran ${duration} s against the guest" || nok "the test client failed (exit $crc): $(tail -3 "$results/client.txt")"
# The rate is a figure, not an assertion (performance targets
# are shown by benchmarks, never by timed assertions): under icount sleep=on
# guest time runs at ~1/3 of real time, so a 1 ms servo answers ~300-350 times
# per real second here; on KVM or bare metal, 1000.
rate=$(sv sample_rate_hz)
echo "# FIGURE sample rate: ${rate:-?} Hz real time (spec: >= 333 = 1 per 3 ms; ours: 1000) - $(awk -v r="${rate:-0}" 'BEGIN { print (r >= 333 ? "meets the spec" : "below the spec") }') under $(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1)"
echo "# FIGURE loss $(sv loss_ratio), rtt mean $(sv rtt_ms_mean) ms, max $(sv rtt_ms_max) ms"
check_num "answers received (at least 1000 in the run)" "$(sv answers)" '>=' 1000
check_num "loss ratio (spec: < 0.1)" "$(sv loss_ratio)" '<' 0.1
check_num "the user moved the handle (m)" "$(sv handle_travel_m)" '>=' 0.02
check_num "the coupled sphere followed (m)" "$(sv coupled_travel_m)" '>=' 0.02
# The coupling stiffness at 1 ms is the joint-space passivity bound at 2T
# (203 N/m, control.md): the same forces deflect it about 7x more than the
# former 1500 N/m, whose limit here was 5 mm.
check_num "coupling error, mean (m)" "$(sv coupling_error_mean_m)" '<=' 0.02
[ "$(cat "$results/second_client.rc" 2>/dev/null)" != 0 ] && ok "a second client from another source port is refused" || nok "the second client was not refused: $(tail -2 "$results/second_client.txt")"
check_num "module: exactly one session opened" "$(gv hap_stats.txt sessions_opened)" '==' 1
check_num "bridge: hostile datagrams dropped" "$(gv proto_interface.txt rejected)" '>=' 10000
if [ "$insecure" = 1 ]; then
  check_num "bridge: unauthenticated v1, as asked (--insecure)" "$(gv proto_interface.txt insecure)" '==' 1
else
  check_num "bridge: the keyless second client's frames refused as unauthenticated" "$(gv proto_interface.txt rejected_unauthenticated_v1)" '>=' 1
  check_num "bridge: authenticated (not --insecure)" "$(gv proto_interface.txt insecure)" '==' 0
fi
check_num "module: nothing malformed reached it" "$(gv hap_stats.txt frames_rejected)" '==' 0
check_num "module: no fail-safe" "$(gv hap_stats.txt fail_safe)" '==' 0
echo "# module: cycles $(gv hap_stats.txt cycles), misses $(gv hap_stats.txt misses) (emulation noise), max consecutive $(gv hap_stats.txt max_consecutive_misses), answers sent $(gv hap_stats.txt answers_sent)"
check_num "simulator log captured (records)" "$(( $(stat -c %s "$results/simlog.bin" 2>/dev/null || echo 0) / 560 ))" '>=' 100
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed (launch script start/stop)" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
echo "e2e: $pass passed, $fail failed"
[ "$fail" = 0 ]
