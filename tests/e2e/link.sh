#!/usr/bin/env bash
# Host <-> guest end-to-end, authenticated (protocol v2), the bridge as the
# unprivileged hapticctrl user. Guest time: `--icount-sleep` (busy time
# counts instructions, idle time follows the host clock, as a UDP link needs;
# plain TCG drives the module into its miss-limit fail-safe within a few
# cycles of insmod, even with the host idle). The test client
# (virtuose_demo, headless) on the host couples to the simulated arm in the
# guest through proto_interface for at least DURATION seconds at 1 kHz and
# until it has MIN_ANSWERS answers; meanwhile a second client from another
# source port must be refused and 10^4 hostile datagrams are sent. Counts
# that depend on the host's speed (what QEMU's user network delivers, how
# fast the guest answers) are checked against what the components counted:
# every datagram the guest's UDP layer delivered was read by the bridge and
# counted once (forwarded or refused by reason), every frame forwarded
# reached the module, every answer the module wrote reached the client or
# is counted lost. Prints every figure, then "N passed, N failed".
# Prints the guest's kernel (`uname -rv`).
#   tests/e2e/link.sh [--stock] [--duration S] [--min-answers N] [--period-us N] [--results DIR]
# --stock: Debian's stock 7.3 rt-amd64 kernel with the module built against
# its headers (make STOCK=1); default: the project's test kernel.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
duration=15; min_answers=3000; period_us=1000; results="$ROOT/build/e2e"; kflag=""
while [ $# -gt 0 ]; do
  case "$1" in
    --duration) duration=$2; shift ;;
    --min-answers) min_answers=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    --results) results=$2; shift ;;
    --stock) kflag=--stock ;;
    *) die "unknown argument $1" ;;
  esac
  shift
done
mkdir -p "$results"; rm -f "$results"/*
. "$ROOT/tests/e2e/lib.sh"
demo="$ROOT/userspace/target/release/virtuose_demo"
(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo) || die "cannot build virtuose_demo"

# HAP_E2E_PORT: the host's UDP port forwarded to the guest (default: a free one).
port=${HAP_E2E_PORT:-$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')}
# Authenticated (protocol v2): the bridge gets the key, so does the test
# client; the second client has none. HAP_E2E_INSECURE=1: the bridge and the
# client speak the unauthenticated v1 (the bridge's --insecure).
key=$(hap_keyfile "$ROOT/build/hap-test.key")
insecure=${HAP_E2E_INSECURE:-0}
if [ "$insecure" = 1 ]; then bridge_auth=(--insecure-bridge); client_key=(); else bridge_auth=(--key "$key"); client_key=(--key "$key"); fi
max_s=$((duration * 8 + 60))
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background $kflag ${HAP_E2E_QEMU:---icount} --udp "$port:5000" "${bridge_auth[@]}" \
  --log "$results/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$ROOT/tests/guest/serve.sh" "$period_us" $((max_s + 60)))
# qpid is the subshell that waits for QEMU: stop QEMU itself too.
stop_guest() { pkill -P "$qpid" 2>/dev/null; kill "$qpid" 2>/dev/null; }
trap stop_guest EXIT
for _ in $(seq 3000); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; die "the guest did not get ready"; }
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# guest ready ($(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1), servo period ${period_us} us); UDP 127.0.0.1:$port -> guest:5000"

if [ "${HAP_E2E_NO_HOSTILE:-0}" = 1 ]; then true & else
python3 "$ROOT/tests/e2e/udp_garbage.py" 127.0.0.1 "$port" 10000 3 > "$results/garbage.txt" 2>&1 &
fi
gpid=$!
( sleep 4; HAP_KEY_FILE= timeout 30 "$demo" --server "127.0.0.1#$port" --headless --duration 2 --timeout-ms 300 > "$results/second_client.txt" 2>&1; echo $? > "$results/second_client.rc" ) &
spid=$!
"$demo" --server "127.0.0.1#$port" "${client_key[@]}" --headless --timeout-ms 1000 --duration "$duration" --answers "$min_answers" \
  --max-duration "$max_s" --results "$results" > "$results/client.txt" 2>&1
crc=$?
wait "$gpid" "$spid"
for _ in $(seq 1200); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
stop_guest
trap - EXIT

sed 's/^/# client: /' "$results/client.txt" | grep -E 'summary|sample_rate|loss|rtt|coupling|travel|answers|lost|error' | head -20
sed 's/^/# /' "$results/garbage.txt"
sv() { sed -n "s/^$1: //p" "$results/summary.txt" 2>/dev/null | head -1; }
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt"
between HAP-PROTO > "$results/proto_interface.txt"
between HAP-SIMLOG | sed -E 's/\[ *[0-9]+\.[0-9]+\] .*$//' | grep -E "^[A-Za-z0-9+/=]+$" | base64 -d 2>/dev/null | gzip -dc > "$results/simlog.bin" 2>/dev/null
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }

[ "$crc" = 0 ] && ok "the test client ran against the guest" || nok "the test client failed (exit $crc): $(tail -3 "$results/client.txt")"
# Rates are figures, not assertions: under icount sleep=on a busy guest's
# time runs slower than real time (a 1 ms servo answers a few hundred times
# per real second here; on KVM or bare metal, 1000).
rate=$(sv sample_rate_hz)
echo "# FIGURE sample rate: ${rate:-?} Hz real time (spec: >= 333 = 1 per 3 ms; ours: 1000) - $(awk -v r="${rate:-0}" 'BEGIN { print (r >= 333 ? "meets the spec" : "below the spec") }') under $(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1); run $(sv duration_s) s"
echo "# FIGURE loss $(sv loss_ratio), rtt mean $(sv rtt_ms_mean) ms, max $(sv rtt_ms_max) ms; VPr sent $(sv vpr_sent), held back by the client's pacing $(sv vpr_held)"
check_num "answers received (the client runs until it has $min_answers, at most ${max_s} s)" "$(sv answers)" '>=' "$min_answers"
check_num "loss ratio (sequence gaps; spec: < 0.1)" "$(sv loss_ratio)" '<' 0.1
check_num "the user moved the handle (m)" "$(sv handle_travel_m)" '>=' 0.02
check_num "the coupled sphere followed (m)" "$(sv coupled_travel_m)" '>=' 0.02
# Coupling error: the coupling is a spring K_t between the handle and the
# sphere (virtuose_demo: m = 0.5 kg, drag b = 10 N s/m; walls, floor and
# sphere B by contact springs). K_t is the passivity bound at the servo
# period (control.md: 203 N/m at 1 ms, proportional to 1/T up to 1500 N/m).
# Whatever holds the sphere back (its drag, b v / K_t = 49 ms x v at 1 ms; a
# wall the walk pushes the handle beyond; sphere B), the spring's stretch is
# the force it carries over K_t. So the mean error must be the mean
# coupling force received over K_t, plus 2 mm for the age of the answers
# (the sphere moves on while an answer travels); a sphere running away (a
# delayed spring is active) would leave it far behind. And no force exceeds
# 20 N, so no error held by the spring exceeds 20 N / K_t.
kt=$(awk -v p="$period_us" 'BEGIN { k = 203 * 1000 / p; if (k > 1500) k = 1500; printf "%.1f", k }')
elim=$(awk -v f="$(sv coupling_force_mean_n)" -v k="$kt" 'BEGIN { if (f != "") printf "%.5f", f / k + 0.002 }')
echo "# FIGURE coupling error mean $(sv coupling_error_mean_m) m, max $(sv coupling_error_max_m) m over the cycles with a fresh loop ($(sv stale_cycles) client cycles with an answer older than 100 ms left the sphere to its drag); mean coupling force $(sv coupling_force_mean_n) N (K_t $kt N/m); free sphere (no contact): mean $(sv free_coupling_error_mean_m) m over $(sv free_samples) cycles, handle speed $(sv free_handle_speed_mean_m_s) m/s"
check_num "coupling error, mean (m; mean force / K_t + 2 mm)" "$(sv coupling_error_mean_m)" '<=' "$elim"
check_num "coupling error, max (m; 20 N / K_t)" "$(sv coupling_error_max_m)" '<' "$(awk -v k="$kt" 'BEGIN { printf "%.5f", 20 / k }')"
[ "$(cat "$results/second_client.rc" 2>/dev/null)" != 0 ] && ok "a second client from another source port is refused" || nok "the second client was not refused: $(tail -2 "$results/second_client.txt")"
check_num "module: exactly one session opened" "$(gv hap_stats.txt sessions_opened)" '==' 1
check_num "bridge and module count the same sessions" "$(gv proto_interface.txt sessions_opened)" '==' "$(gv hap_stats.txt sessions_opened)"
# Accounting, component by component.
rcv=$(gv proto_interface.txt received); fwd=$(gv proto_interface.txt forwarded); rej=$(gv proto_interface.txt rejected)
acct=$(sum "$(gv proto_interface.txt forwarded)" "$(gv proto_interface.txt write_errors)" "$(gv proto_interface.txt retransmits_reacked)" "$(gv proto_interface.txt proofs_reacked)" "$rej" "$(gv proto_interface.txt cookies_sent)")
udp=$(sed -n 's/^HAP-UDP .*InDatagrams=\([0-9]*\).*/\1/p' "$qlog" | tr -d '\r' | head -1)
rcvbuf=$(sed -n 's/^HAP-UDP .*RcvbufErrors=\([0-9]*\).*/\1/p' "$qlog" | tr -d '\r' | head -1)
sent_hostile=$(sed -n 's/^sent \([0-9]*\) hostile.*/\1/p' "$results/garbage.txt")
echo "# FIGURE datagrams: the guest's UDP delivered $udp to the bridge ($rcvbuf dropped for a full receive buffer); hostile sent ${sent_hostile:-0}, client VPr sent $(sv vpr_sent): QEMU's user network delivered what the emulated guest could take"
check_num "guest: every datagram delivered to the bridge's socket was read (UDP InDatagrams = bridge received)" "$rcv" '==' "$udp"
check_num "bridge: each datagram counted once (received = forwarded + write errors + re-acked + a proof's session_ack again + refused by reason + answered with a cookie)" "$rcv" '==' "$acct"
check_num "bridge: no write error to rtf_in" "$(gv proto_interface.txt write_errors)" '==' 0
check_num "bridge: hostile datagrams refused (bad magic, sizes, unauthenticated v1, rate limited)" "$(sum "$(gv proto_interface.txt rejected_bad_magic)" "$(gv proto_interface.txt rejected_oversize)" "$(gv proto_interface.txt rejected_undersize)")" '>=' 1
check_num "module: every forwarded frame arrived (frames_in = bridge forwarded + the bridge's own session closes)" "$(gv hap_stats.txt frames_in)" '==' "$(sum "$fwd" "$(gv proto_interface.txt kernel_closes)")"
check_num "bridge: read every frame the module wrote (answers = module frames_out + replies)" "$(gv proto_interface.txt answers)" '==' "$(sum "$(gv hap_stats.txt frames_out)" "$(gv hap_stats.txt replies)")"
check_num "bridge: sent every one to the client (sent = answers - no client - unsealed)" "$(gv proto_interface.txt sent)" '==' "$(sum "$(gv proto_interface.txt answers)" "-$(gv proto_interface.txt answers_no_client)" "-$(gv proto_interface.txt answers_unsealed)")"
if [ "$insecure" = 1 ]; then
  check_num "bridge: unauthenticated v1, as asked (--insecure)" "$(gv proto_interface.txt insecure)" '==' 1
else
  check_num "bridge: the keyless second client's frames refused as unauthenticated" "$(gv proto_interface.txt rejected_unauthenticated_v1)" '>=' 1
  check_num "bridge: authenticated (not --insecure)" "$(gv proto_interface.txt insecure)" '==' 0
fi
bid=$(sed -n 's/^HAP-BRIDGE-ID //p' "$qlog" | tr -d '\r' | head -1)
echo "# bridge identity: $bid"
check_num "bridge: runs as the unprivileged hapticctrl user (uid)" "$(echo "$bid" | sed -n 's/.*uid=\([0-9]*\).*/\1/p')" '==' 990
check_num "bridge: no capability left (CapEff, no real-time priority asked)" "$((16#$(echo "$bid" | sed -n 's/.*capeff=\([0-9a-f]*\).*/\1/p')))" '==' 0
check_num "module: nothing malformed reached it" "$(gv hap_stats.txt frames_rejected)" '==' 0
check_num "module: no fail-safe" "$(gv hap_stats.txt fail_safe)" '==' 0
echo "# module: cycles $(gv hap_stats.txt cycles), misses $(gv hap_stats.txt misses) (emulation noise), max consecutive $(gv hap_stats.txt max_consecutive_misses), answers sent $(gv hap_stats.txt answers_sent)"
check_num "simulator log captured (records)" "$(( $(stat -c %s "$results/simlog.bin" 2>/dev/null || echo 0) / 560 ))" '>=' 100
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed (launch script start/stop)" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
echo "e2e: $pass passed, $fail failed"
[ "$fail" = 0 ]
