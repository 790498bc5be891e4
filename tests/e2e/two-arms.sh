#!/usr/bin/env bash
# Host <-> guest end-to-end with two arms (arms=2): two clients at once, one
# per arm, each through its arm's bridge on its own UDP port (5000, 5001 in
# the guest), authenticated (protocol v2). Guest time: tcg-icount, as the
# one-arm link run. Both clients (virtuose_demo, headless) couple their arm;
# once arm 0 has been coupled NEED cycles its client is killed (SIGKILL: no
# close, its link is lost) while arm 1's goes on: arm 0 fades and its bridge
# closes the silent session, arm 1 stays coupled and not fading; once arm 1
# has been coupled NEED cycles too its client ends (SIGTERM: it closes its
# session). Checked: both arms coupled >= 10^4 cycles, 0 misses, no
# fail-safe; each arm's frames came from its own bridge only; each position
# log complete; one stop request cuts both motor lines in order (every
# arm's inhibited before any is powered off). Prints every figure, then
# "N passed, N failed".
#   tests/e2e/two-arms.sh [--stock] [--period-us N] [--need N] [--results DIR]
# HAP_E2E_PORT, HAP_E2E_PORT1: the host's UDP ports forwarded to the guest's
# 5000 and 5001 (default: free ones).
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
period_us=1000; need=11000; results="$ROOT/build/e2e-arms"; kflag=""
while [ $# -gt 0 ]; do
  case "$1" in
    --period-us) period_us=$2; shift ;;
    --need) need=$2; shift ;;
    --results) results=$2; shift ;;
    --stock) kflag=--stock ;;
    *) die "unknown argument $1" ;;
  esac
  shift
done
mkdir -p "$results/arm0" "$results/arm1"; rm -f "$results"/*.txt "$results"/arm?/*
. "$ROOT/tests/e2e/lib.sh"
demo="$ROOT/userspace/target/release/virtuose_demo"
(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_demo) || die "cannot build virtuose_demo"
free_port() { python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
port0=${HAP_E2E_PORT:-$(free_port)}
port1=${HAP_E2E_PORT1:-$(free_port)}
[ "$port0" != "$port1" ] || die "the two arms need two ports ($port0)"
key=$(hap_keyfile "$ROOT/build/hap-test.key")
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background $kflag --icount \
  --udp "$port0:5000" --udp "$port1:5001" --key "$key" \
  --log "$results/guest.log" --extra "$ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$ROOT/tests/guest/serve-arms.sh" "$period_us" 900 "$need")
stop_guest() { pkill -P "$qpid" 2>/dev/null; kill "$qpid" 2>/dev/null; }
cpids=()
stop_all() { for p in "${cpids[@]+"${cpids[@]}"}"; do kill -KILL "$p" 2>/dev/null; done; stop_guest; }
trap stop_all EXIT
# wait_for PATTERN SECONDS: the guest log shows PATTERN (the guest alive).
wait_for() {
  local _
  for _ in $(seq $(($2 * 10))); do
    grep -q "$1" "$qlog" 2>/dev/null && return 0
    kill -0 "$qpid" 2>/dev/null || return 1
    sleep 0.1
  done
  return 1
}
wait_for HAP-READY 300 || { tail -30 "$qlog"; die "the guest did not get ready"; }
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# guest ready ($(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1), servo period ${period_us} us, 2 arms); arm 0: UDP 127.0.0.1:$port0 -> guest:5000, arm 1: 127.0.0.1:$port1 -> guest:5001"
client() { # ARM PORT
  exec "$demo" --server "127.0.0.1#$2" --key "$key" --headless --timeout-ms 1000 --duration 0 --max-duration 1200 \
    --results "$results/arm$1" > "$results/arm$1/client.txt" 2>&1
}
client 0 "$port0" & pa=$!
client 1 "$port1" & pb=$!
cpids=("$pa" "$pb")
t0=$(date +%s)
if wait_for HAP-ARM0-COUPLED 900; then
  ok "arm 0 coupled $need cycles with both clients running ($(( $(date +%s) - t0 )) s real time)"
else
  nok "arm 0 never coupled $need cycles: $(tail -3 "$results/arm0/client.txt")"
fi
# Arm 0's client vanishes: no close, its link is lost.
kill -KILL "$pa" 2>/dev/null; wait "$pa" 2>/dev/null
if wait_for HAP-ARM1-DONE 900; then
  ok "arm 0's session closed by its bridge, arm 1 coupled $need cycles"
else
  nok "the guest did not see arm 0's session closed and arm 1 coupled $need cycles"
fi
kill -TERM "$pb" 2>/dev/null; wait "$pb"; crc=$?
cpids=()
for _ in $(seq 1200); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
stop_guest
trap - EXIT

between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
for a in 0 1; do
  between "HAP-STATS$a" > "$results/hap_stats$a.txt"
  between "HAP-PROTO$a" > "$results/proto_interface$a.txt"
  between "HAP-SIMLOG$a-SUMMARY" > "$results/simlog$a.txt"
done
between HAP-CUT > "$results/cut.txt"
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }
sv() { sed -n "s/^$1: //p" "$results/arm1/summary.txt" 2>/dev/null | head -1; }
marker() { sed -n "s/^$1 //p" "$qlog" | tr -d '\r' | head -1; }
field() { echo "$1" | sed -n "s/.*$2=\([0-9a-fx]*\).*/\1/p"; }

[ "$crc" = 0 ] && ok "arm 1's client ran and closed its session" || nok "arm 1's client failed (exit $crc): $(tail -3 "$results/arm1/client.txt")"
sed 's/^/# arm 1 client: /' "$results/arm1/client.txt" | grep -E 'answers|loss|rtt|travel|error' | head -12
coupled=$(marker HAP-COUPLED)
echo "# FIGURE coupled cycles: $coupled (tcg-icount, ${period_us} us)"
check_num "arm 0 coupled cycles (>= 10^4)" "$(field "$coupled" arm0)" '>=' 10000
check_num "arm 1 coupled cycles (>= 10^4)" "$(field "$coupled" arm1)" '>=' 10000
fade=$(marker HAP-FADE); echo "# arm 0 fading: $fade"
st1=$(field "$fade" arm1_status)
[ -n "$fade" ] && ok "arm 0 fades once its client is gone" || nok "arm 0 never seen fading"
check_num "arm 1 coupled in the same sample (status & COUPLED)" "$(( ${st1:-0} & 128 ))" '==' 128
check_num "arm 1 not fading in the same sample (status & LINK_FADING)" "$(( ${st1:-256} & 256 ))" '==' 0
check_num "arm 1's session open in the same sample" "$(field "$fade" arm1_session)" '>' 0
closed=$(marker HAP-ARM0-CLOSED); echo "# arm 0 closed: $closed"
check_num "arm 1 still coupled when arm 0's session was closed" "$(( $(field "$closed" arm1_status) & 128 ))" '==' 128
check_num "arm 1 answers received" "$(sv answers)" '>=' 10000
check_num "arm 1 loss ratio (sequence gaps; spec: < 0.1)" "$(sv loss_ratio)" '<' 0.1
check_num "arm 1: the coupled sphere followed (m)" "$(sv coupled_travel_m)" '>=' 0.02
check_num "no deadline miss with two arms and two clients" "$(gv hap_stats0.txt misses)" '==' 0
echo "# module: cycles $(gv hap_stats0.txt cycles), misses $(gv hap_stats0.txt misses)"
for a in 0 1; do
  check_num "arm $a: no fail-safe before the stop request" "$(gv hap_stats$a.txt fail_safe)" '==' 0
  check_num "arm $a: exactly one session opened" "$(gv hap_stats$a.txt sessions_opened)" '==' 1
  check_num "arm $a: its bridge counted the same sessions" "$(gv proto_interface$a.txt sessions_opened)" '==' 1
  # Each arm's frames came from its own bridge only.
  check_num "arm $a: every frame it got came from its bridge (frames_in = forwarded + the bridge's own closes)" \
    "$(gv hap_stats$a.txt frames_in)" '==' "$(sum "$(gv proto_interface$a.txt forwarded)" "$(gv proto_interface$a.txt kernel_closes)")"
  check_num "arm $a: its bridge read every answer it wrote (answers = frames_out + replies)" \
    "$(gv proto_interface$a.txt answers)" '==' "$(sum "$(gv hap_stats$a.txt frames_out)" "$(gv hap_stats$a.txt replies)")"
  check_num "arm $a: nothing malformed reached it" "$(gv hap_stats$a.txt frames_rejected)" '==' 0
  check_num "arm $a: position log, no record dropped" "$(gv simlog$a.txt dropped_records)" '==' 0
  check_num "arm $a: position log records (>= its coupled cycles)" "$(gv simlog$a.txt records)" '>=' "$(field "$coupled" arm$a)"
done
check_num "arm 0's bridge closed its silent session (kernel_closes)" "$(gv proto_interface0.txt kernel_closes)" '>=' 1
sed 's/^/# stop: step arm gate supply: /' "$results/cut.txt"
# Step 1 leaves each arm's supply as it was: arm 0's on (its client
# vanished), arm 1's as its client's close left it.
want1="1 0 fail_safe $(gv hap_stats0.txt power),1 1 fail_safe $(gv hap_stats1.txt power),"
[ "$(sed -n 1,2p "$results/cut.txt" | tr '\n' ,)" = "$want1" ] \
  && ok "stop: step 1 inhibits arm 0, then arm 1, supplies untouched ($want1)" || nok "stop: step 1 not as expected: $(sed -n 1,2p "$results/cut.txt" | tr '\n' ,), want $want1"
[ "$(sed -n 3,4p "$results/cut.txt" | tr '\n' ,)" = "2 0 fail_safe 0,2 1 fail_safe 0," ] \
  && ok "stop: step 2 powers off arm 0, then arm 1" || nok "stop: step 2 not as expected: $(sed -n 3,4p "$results/cut.txt" | tr '\n' ,)"
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
echo "e2e-arms: $pass passed, $fail failed"
[ "$fail" = 0 ]
