#!/usr/bin/env bash
# Host <-> guest end-to-end through the link emulator: the test client
# (virtuose_demo, headless: sphere A coupled to the arm, the box's stiff
# walls and floor, the free sphere B) talks to hap-netem on loopback, which
# delays, jitters, reorders, drops and duplicates the datagrams both ways on
# their way to and from QEMU's forward to proto_interface in the guest
# (authenticated, protocol v2; guest time as tests/e2e/link.sh: --icount,
# HAP_E2E_QEMU=--icount-sleep for the other). The user
# walks the handle (tests/data/walk.eff).
#
# Asserts the link's done-when: the handle stays coupled (the module's
# position log: every cycle in session with a VPr at full link gain, no
# fade event; where the host itself stalled the link beyond the fade's
# start in guest time, as the proxy's trace shows, no more fades than such
# stalls), no deadline miss, no fail-safe, and every count reconciles
# component by component (client -> proxy -> QEMU -> bridge -> module and
# back). Prints every figure: the proxy's counters per direction, the
# bridge's refusals by reason (reordered and duplicated frames meet
# protocol v2's replay window), the client's answers, losses, stale and
# duplicate answers, its round trip, and the cycles its own 100 ms horizon
# left uncoupled. Then "e2e-netem: N passed, N failed".
#   tests/e2e/netem.sh [--stock] [--rtt-ms MS] [--jitter-pct P] [--loss-pct P]
#                      [--dup-pct P] [--reorder-pct P] [--seed N] [--duration S]
#                      [--min-answers N] [--period-us N] [--client-window N] [--results DIR]
# Defaults: --rtt-ms 300 --jitter-pct 50 --loss-pct 10 (the slow link).
# --client-window: the client's VPr pacing (virtuose_demo --window; 0: none).
# --link-passivity: the client keeps the link passive (time-domain
# passivity across the link, control.md): it applies the force at any
# delay, and the run also asserts that its end of the link created no
# energy, that the controller's grants reached it, and that the coupled
# sphere followed the handle.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
rtt_ms=300; jitter=50; loss=10; dup=0; reorder=0; seed=1; window=4; link_flag=""
duration=15; min_answers=3000; period_us=1000; results="$ROOT/build/e2e-netem"; kflag=""
while [ $# -gt 0 ]; do
  case "$1" in
    --rtt-ms) rtt_ms=$2; shift ;;
    --jitter-pct) jitter=$2; shift ;;
    --loss-pct) loss=$2; shift ;;
    --dup-pct) dup=$2; shift ;;
    --reorder-pct) reorder=$2; shift ;;
    --seed) seed=$2; shift ;;
    --client-window) window=$2; shift ;;
    --duration) duration=$2; shift ;;
    --min-answers) min_answers=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    --results) results=$2; shift ;;
    --stock) kflag=--stock ;;
    --link-passivity) link_flag=--link-passivity ;;
    *) die "unknown argument $1" ;;
  esac
  shift
done
mkdir -p "$results"; rm -rf "${results:?}"/*
. "$ROOT/tests/e2e/lib.sh"
demo="$ROOT/userspace/target/release/virtuose_demo"
netem="$ROOT/userspace/target/release/hap-netem"
hapctl="$ROOT/userspace/target/release/hapctl"
(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo -p hap-netem -p hapctl) || die "cannot build virtuose_demo, hap-netem, hapctl"

# The proxy refuses bad settings itself (a clear error, exit 2).
"$netem" --upstream 127.0.0.1:9 --rtt-ms "$rtt_ms" --jitter-pct "$jitter" --loss-pct "$loss" \
  --dup-pct "$dup" --reorder-pct "$reorder" --seed "$seed" --duration 0.01 > /dev/null 2> "$results/netem-check.err" \
  || die "bad link settings: $(grep error "$results/netem-check.err")"

# HAP_E2E_PORT: the host's UDP port forwarded to the guest (default: a free one).
port=${HAP_E2E_PORT:-$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')}
key=$(hap_keyfile "$ROOT/build/hap-test.key")
max_s=$((duration * 8 + 60))
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background $kflag ${HAP_E2E_QEMU:---icount} --udp "$port:5000" --key "$key" \
  --log "$results/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$ROOT/tests/guest/serve.sh" "$period_us" $((max_s + 60)))
stop_guest() { pkill -P "$qpid" 2>/dev/null; kill "$qpid" 2>/dev/null; }
npid=""
stop_all() { [ -n "$npid" ] && kill "$npid" 2>/dev/null; stop_guest; }
trap stop_all EXIT
for _ in $(seq 3000); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; die "the guest did not get ready"; }
mode=$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1)
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# guest ready ($mode, servo period ${period_us} us); UDP 127.0.0.1:$port -> guest:5000"

"$netem" --upstream "127.0.0.1:$port" --rtt-ms "$rtt_ms" --jitter-pct "$jitter" --loss-pct "$loss" \
  --dup-pct "$dup" --reorder-pct "$reorder" --seed "$seed" --stats "$results/netem.txt" --trace "$results/netem-trace.csv" \
  > "$results/netem.out" 2> "$results/netem.err" &
npid=$!
for _ in $(seq 100); do grep -q 'listening on' "$results/netem.out" 2>/dev/null && break; sleep 0.05; done
paddr=$(sed -n 's/^hap-netem: listening on \([^,]*\),.*/\1/p' "$results/netem.out")
[ -n "$paddr" ] || die "hap-netem did not start: $(cat "$results/netem.err")"
echo "# $(head -1 "$results/netem.out")"

# The reply timeout of acknowledged requests covers the slowest round trip
# the proxy can make (rtt + jitter), with margin.
tmo=$(awk -v r="$rtt_ms" -v j="$jitter" 'BEGIN { t = 2 * r * (1 + j / 100) + 500; if (t < 1000) t = 1000; printf "%d", t }')
"$demo" --server "${paddr/:/#}" --key "$key" --headless --timeout-ms "$tmo" --window "$window" $link_flag --duration "$duration" --answers "$min_answers" \
  --max-duration "$max_s" --results "$results" > "$results/client.txt" 2>&1
crc=$?
for _ in $(seq 1200); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
stop_guest
# Everything in flight has left the proxy by now (the guest took seconds to
# print its figures): stop it, its last counters go to netem.txt.
kill "$npid"; wait "$npid"; nrc=$?; npid=""
trap - EXIT

sv() { sed -n "s/^$1: //p" "$results/summary.txt" 2>/dev/null | head -1; }
nv() { sed -n "s/^$1: //p" "$results/netem.txt" 2>/dev/null | head -1; }
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt"
between HAP-PROTO > "$results/proto_interface.txt"
between HAP-SIMLOG | sed -E 's/\[ *[0-9]+\.[0-9]+\] .*$//' | grep -E "^[A-Za-z0-9+/=]+$" | base64 -d 2>/dev/null | gzip -dc > "$results/simlog.bin" 2>/dev/null
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }
"$hapctl" analyze "$results/simlog.bin" --out "$results/analysis" --stats "$results/hap_stats.txt" > "$results/analyze.out" 2>&1
av() { sed -n "s/^$1: //p" "$results/analysis/analysis.txt" 2>/dev/null | head -1; }

echo "# link: rtt $rtt_ms ms (one way $(nv to_server_delay_us) us / $(nv to_client_delay_us) us), jitter ±$jitter %, loss $loss %, dup $dup %, reorder $reorder %, seed $seed; client window $window; guest $mode"
for d in to_server to_client; do
  echo "# FIGURE proxy $d: received $(nv ${d}_received), forwarded $(nv ${d}_forwarded), dropped $(nv ${d}_dropped), duplicated $(nv ${d}_duplicated), reordered $(nv ${d}_reordered), in flight $(nv ${d}_in_flight), send errors $(nv ${d}_send_errors); host scheduling: latest send after due $(nv ${d}_late_us_max) us, $(nv ${d}_late_over_1ms) sent > 1 ms late"
done
echo "# FIGURE client: frames sent $(sv frames_sent) (VPr $(sv vpr_sent), held by pacing $(sv vpr_held)), answers $(sv answers), lost $(sv lost) (loss ratio $(sv loss_ratio)), duplicates dropped $(sv duplicates), stale (older) dropped $(sv stale), rtt mean $(sv rtt_ms_mean) ms max $(sv rtt_ms_max) ms, run $(sv duration_s) s, sample rate $(sv sample_rate_hz) Hz real time"
echo "# FIGURE client scene: wall contact $(sv wall_contact_cycles) cycles, free mass contact $(sv free_mass_contact_cycles) cycles (it travelled $(sv free_mass_travel_m) m); handle travel $(sv handle_travel_m) m, coupled sphere travel $(sv coupled_travel_m) m; client cycles with a loop older than its 100 ms horizon (force not applied) $(sv stale_cycles); coupling error mean $(sv coupling_error_mean_m) m"
refusals=$(grep -E '^rejected_[a-z0-9_]+: [1-9]' "$results/proto_interface.txt" | sed 's/^rejected_//' | tr '\n' ' ')
echo "# FIGURE bridge: received $(gv proto_interface.txt received), forwarded $(gv proto_interface.txt forwarded), refused $(gv proto_interface.txt rejected) by reason: ${refusals:-none}; re-acked retransmits $(gv proto_interface.txt retransmits_reacked); answers $(gv proto_interface.txt answers), sent $(gv proto_interface.txt sent)"
# The proxy's trace: the gaps between the datagrams it sent the guest
# (the module's watchdog ages its VPr from one arrival to the next).
gaps=$(awk -F, '$1 == "to_server" && ($5 == "sent" || $5 == "sent_copy") { print $7 }' "$results/netem-trace.csv" | sort -n |
  awk 'NR > 1 { g = ($1 - p) / 1e6; if (g > m) m = g; if (g > 50) n++ } { p = $1 } END { printf "max %.1f ms, %d over 50 ms", m, n }')
echo "# FIGURE proxy to_server gaps between datagrams sent (real time): $gaps"
# A gap the host makes (the client or the proxy not scheduled for seconds on
# a loaded machine) is not the emulated link: the guest, whose clock runs at
# its own rate under icount, sees it as a silent client, and the watchdog
# rightly starts its fade once the gap passes LINK_FADE_START_US (50 ms) of
# guest time. The guest's rate over the run is its cycles over the client's
# real run time; a gap counts as a host stall when, at that rate, it exceeds
# the fade's start. Only gaps between two datagrams of the VPr stream
# count (the stream's length, the most common one): the set-up's and the
# close's gaps come before and after it, where the module couples nothing.
guest_rate=$(awk -v c="$(gv hap_stats.txt cycles)" -v p="$period_us" -v d="$(sv duration_s)" \
  'BEGIN { if (d > 0 && c > 0) printf "%.4f", c * p / 1e6 / d; else print 1 }')
stalls=$(awk -F, '$1 == "to_server" && ($5 == "sent" || $5 == "sent_copy") { print $7, $3 }' "$results/netem-trace.csv" | sort -n |
  awk -v r="$guest_rate" '{ t[NR] = $1; l[NR] = $2; c[$2]++ }
    END { for (k in c) if (c[k] > c[m] || m == "") m = k
          for (i = 2; i <= NR; i++) if (l[i] == m && l[i - 1] == m && (t[i] - t[i - 1]) / 1e6 * r > 50) n++
          print n + 0 }')
echo "# FIGURE guest clock at $guest_rate of real time; host stalls of the link longer than the fade's start in guest time: $stalls"
echo "# FIGURE module: cycles $(gv hap_stats.txt cycles), misses $(gv hap_stats.txt misses), VPr extrapolated $(gv hap_stats.txt vpr_extrapolated), frames in $(gv hap_stats.txt frames_in), out $(gv hap_stats.txt frames_out); position log: $(av link_cycles) cycles powered in session with a VPr, at full link gain $(av link_full_gain_fraction), $(av link_fades) fades, lowest gain $(av link_gain_min), oldest VPr $(av vpr_age_max_ms) ms (fade events counted unpowered too: $(av link_fading_events))"

echo "# FIGURE client link ledger (J): its port put in $(sv link_energy_in_j), took out $(sv link_energy_out_j); granted the controller $(sv link_granted_j), received $(sv link_received_j); reservoir $(sv link_reservoir_j)"
[ "$crc" = 0 ] && ok "the test client ran through the proxy against the guest" || nok "the test client failed (exit $crc): $(tail -3 "$results/client.txt")"
[ "$nrc" = 0 ] && ok "the proxy ended cleanly" || nok "the proxy failed (exit $nrc): $(tail -3 "$results/netem.err")"
check_num "answers received (at least $min_answers, at most ${max_s} s)" "$(sv answers)" '>=' "$min_answers"
check_num "the user moved the handle (m)" "$(sv handle_travel_m)" '>=' 0.02
check_num "module: exactly one session opened" "$(gv hap_stats.txt sessions_opened)" '==' 1
# The done-when: coupled over the whole run, wherever the host delivered
# the link; a fade only where the host itself stalled it.
if [ "$stalls" = 0 ]; then
  check_num "module: the handle stayed coupled (cycles powered in session with a VPr at full link gain, fraction)" "$(av link_full_gain_fraction)" '==' 1
  check_num "module: no fade while powered in session" "$(av link_fades)" '==' 0
else
  echo "# FIGURE the host stalled the link $stalls time(s) beyond the fade's start: full link gain in $(av link_full_gain_fraction) of the powered cycles"
  check_num "module: no fade but where the host stalled the link (fades)" "$(av link_fades)" '<=' "$stalls"
  check_num "module: the coupling came back after the stalls (cycles at full link gain, fraction)" "$(av link_full_gain_fraction)" '>=' 0.5
fi
if [ -n "$link_flag" ]; then
  check_num "client: its end of the link created no energy (reservoir, J)" "$(sv link_reservoir_j)" '>=' -0.000001
  check_num "client: the controller's grants reached it (J)" "$(sv link_received_j)" '>' 0
  # Whether the walk brings the sphere to a wall or to the free mass
  # depends on how fast the guest runs next to the client (a loaded 2-core
  # host runs it at a sixth of real time): the contacts are a figure above;
  # the link's coupling is asserted on what the sphere did for sure.
  check_num "client: the coupled sphere followed the handle through the link (its travel, m)" "$(sv coupled_travel_m)" '>=' 0.05
fi
check_num "module: no deadline miss" "$(gv hap_stats.txt misses)" '==' 0
check_num "module: no fail-safe" "$(gv hap_stats.txt fail_safe)" '==' 0
check_num "module: nothing malformed reached it" "$(gv hap_stats.txt frames_rejected)" '==' 0
check_num "position log captured (records)" "$(av servo_records)" '>=' 100
# Accounting, hop by hop.
for d in to_server to_client; do
  check_num "proxy $d: its counts reconcile (received + duplicated = forwarded + dropped + in flight + send errors)" \
    "$(sum "$(nv ${d}_received)" "$(nv ${d}_duplicated)")" '==' "$(sum "$(nv ${d}_forwarded)" "$(nv ${d}_dropped)" "$(nv ${d}_in_flight)" "$(nv ${d}_send_errors)")"
  check_num "proxy $d: nothing left in flight at the end" "$(nv ${d}_in_flight)" '==' 0
done
check_num "proxy: every frame the client sent arrived at the proxy" "$(nv to_server_received)" '==' "$(sv frames_sent)"
check_num "proxy: one client" "$(nv clients)" '==' 1
rcv=$(gv proto_interface.txt received); fwd=$(gv proto_interface.txt forwarded); rej=$(gv proto_interface.txt rejected)
udp=$(sed -n 's/^HAP-UDP .*InDatagrams=\([0-9]*\).*/\1/p' "$qlog" | tr -d '\r' | head -1)
rcvbuf=$(sed -n 's/^HAP-UDP .*RcvbufErrors=\([0-9]*\).*/\1/p' "$qlog" | tr -d '\r' | head -1)
echo "# FIGURE QEMU's user network: proxy forwarded $(nv to_server_forwarded), the guest's UDP delivered $udp ($rcvbuf dropped for a full receive buffer); the bridge sent $(gv proto_interface.txt sent), the proxy received $(nv to_client_received)"
check_num "QEMU: no more datagrams reached the guest than the proxy forwarded" "$udp" '<=' "$(nv to_server_forwarded)"
check_num "guest: every datagram delivered to the bridge's socket was read (UDP InDatagrams = bridge received)" "$rcv" '==' "$udp"
check_num "bridge: each datagram counted once (received = forwarded + write errors + re-acked + a proof's session_ack again + refused by reason + answered with a cookie)" "$rcv" '==' \
  "$(sum "$fwd" "$(gv proto_interface.txt write_errors)" "$(gv proto_interface.txt retransmits_reacked)" "$(gv proto_interface.txt proofs_reacked)" "$rej" "$(gv proto_interface.txt cookies_sent)")"
check_num "bridge: the refusals add up by reason" "$rej" '==' "$(sum $(sed -n 's/^rejected_[a-z0-9_]*: \([0-9]*\)$/\1/p' "$results/proto_interface.txt"))"
check_num "module: every forwarded frame arrived (frames_in = bridge forwarded + the bridge's own session closes)" "$(gv hap_stats.txt frames_in)" '==' "$(sum "$fwd" "$(gv proto_interface.txt kernel_closes)")"
check_num "bridge: read every frame the module wrote (answers = module frames_out + replies)" "$(gv proto_interface.txt answers)" '==' "$(sum "$(gv hap_stats.txt frames_out)" "$(gv hap_stats.txt replies)")"
check_num "bridge: sent every one to the client (sent = answers - no client - unsealed)" "$(gv proto_interface.txt sent)" '==' "$(sum "$(gv proto_interface.txt answers)" "-$(gv proto_interface.txt answers_no_client)" "-$(gv proto_interface.txt answers_unsealed)")"
check_num "QEMU: no more datagrams reached the proxy than the bridge sent (answers + cookies + answered refusals + re-acks + session_acks again)" "$(nv to_client_received)" '<=' \
  "$(sum "$(gv proto_interface.txt sent)" "$(gv proto_interface.txt cookies_sent)" "$(gv proto_interface.txt refusals_answered)" "$(gv proto_interface.txt retransmits_reacked)" "$(gv proto_interface.txt proofs_reacked)")"
check_num "client: took no more answers (accepted + duplicates + stale) than the proxy forwarded to it" "$(sum "$(sv answers)" "$(sv duplicates)" "$(sv stale)")" '<=' "$(nv to_client_forwarded)"
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed (launch script start/stop)" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
echo "e2e-netem: $pass passed, $fail failed"
[ "$fail" = 0 ]
