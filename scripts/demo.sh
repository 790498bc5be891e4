#!/usr/bin/env bash
# The main job, from a fresh Debian 12 machine: set everything up, boot the
# QEMU guest with the controller (launch script: proto_interface + module)
# and a scripted user walking the handle around, run the test client on the
# host against the forwarded UDP port (3D page + terminal summary), then
# leave the figures and plots of the run in a results folder.
#   scripts/demo.sh [--duration S] [--headless] [--http ADDR] [--results DIR] [--period-us N]
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"

duration=30; headless=0; http=127.0.0.1:8080; results="$HAP_ROOT/results/demo-$(date +%Y%m%d-%H%M%S)"; period_us=""
while [ $# -gt 0 ]; do
  case "$1" in
    --duration) duration=$2; shift ;;
    --headless) headless=1 ;;
    --http) http=$2; shift ;;
    --results) results=$2; shift ;;
    --period-us) period_us=$2; shift ;;
    -h|--help) sed -n '2,7p' "$0"; exit 0 ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done
case "$duration" in ''|*[!0-9]*) die "--duration takes whole seconds" ;; esac

bash "$HERE/setup-toolchain.sh"
bash "$HERE/build-kernel.sh" >/dev/null
make -s -C "$HAP_ROOT"
bash "$HERE/build-userspace-static.sh"
log "building the host tools (virtuose_demo, hapctl)"
(cd "$HAP_ROOT/userspace" && cargo build --release --quiet -p virtuose_demo -p hapctl)
mkdir -p "$results"

# KVM where it works (real time, 1 ms period); otherwise TCG with icount
# sleep=on, where a 1 ms servo keeps up (timing.md) at a fraction of real time.
accel_opts=(--icount-sleep); period_us=${period_us:-1000}
if [ "${HAP_ACCEL:-}" = kvm ]; then accel_opts=(--accel kvm); fi
port=$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
# Authenticated (protocol v2): one key for the bridge in the guest and the client.
key=$(hap_keyfile "$HAP_ROOT/build/hap-demo.key")
read -r qpid qlog < <(bash "$HERE/qemu-run.sh" --background "${accel_opts[@]}" --udp "$port:5000" --key "$key" \
  --log "$results/guest.log" --extra "$HAP_ROOT/tests/data/walk.eff:/data/effort.eff" \
  "$HAP_ROOT/tests/guest/serve.sh" "$period_us" $((duration + 120)))
trap 'kill $qpid 2>/dev/null || true' EXIT
for _ in $(seq 900); do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; die "the guest did not start (log: $qlog)"; }
mode=$(sed -n 's/.*hap\.mode=\([^ ]*\).*/\1/p' "$qlog" | head -1)
log "guest up (accelerator: $mode, servo period ${period_us} us); controller at 127.0.0.1:$port"
# The run's mode for the report (every figure names the mode it came from).
printf 'accelerator: %s\nservo_period_us: %s\nclient_duration_s: %s\nkernel: %s\n' "$mode" "$period_us" "$duration" \
  "$(sed -n 's/.*Linux version \([^ ]*\) .*#[0-9]* \([A-Z_ ]*PREEMPT[A-Z_]*\).*/\1 \2/p' "$qlog" | head -1)" > "$results/run.txt"

client=("$HAP_ROOT/userspace/target/release/virtuose_demo" --server "127.0.0.1#$port" --key "$key" --duration "$duration" --results "$results")
cpid=""; client_rc=0
if [ "$headless" = 1 ]; then
  client+=(--headless)
  "${client[@]}" | tee "$results/client.txt" || client_rc=$?
else
  # The page stays up after the run and links to the run's report once
  # hapctl analyze has written it.
  client+=(--http "$http" --linger 600); log "3D page: http://$http/ (the client prints it too)"
  "${client[@]}" > >(tee "$results/client.txt") &
  cpid=$!
  trap 'kill $qpid $cpid 2>/dev/null || true' EXIT
  while kill -0 "$cpid" 2>/dev/null && [ ! -s "$results/summary.txt" ]; do sleep 0.5; done
  if ! kill -0 "$cpid" 2>/dev/null; then wait "$cpid" || client_rc=$?; cpid=""; fi
fi
# A client that failed (no session, lost controller) leaves the run to the
# guest's own end; what it recorded is still collected and analysed.
if [ "$client_rc" != 0 ]; then
  log "the client failed (exit $client_rc; client.txt); collecting what the guest recorded"
fi

for _ in $(seq 1800); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
if [ -n "$cpid" ]; then trap 'kill $cpid 2>/dev/null || true' EXIT; else trap - EXIT; fi
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt" || true
between HAP-HIST > "$results/hap_hist.txt" || true
between HAP-PROTO > "$results/proto_interface.txt" || true
between HAP-SIMLOG-SUMMARY > "$results/simlog.txt" || true
between HAP-SIMLOG | sed -E 's/\[ *[0-9]+\.[0-9]+\] .*$//' | grep -E "^[A-Za-z0-9+/=]+$" | base64 -d 2>/dev/null | gzip -dc > "$results/simlog.bin" 2>/dev/null || true
report=""
if [ -s "$results/simlog.bin" ]; then
  extra=()
  [ -s "$results/hap_stats.txt" ] && extra+=(--stats "$results/hap_stats.txt")
  [ -s "$results/hap_hist.txt" ] && extra+=(--hist "$results/hap_hist.txt")
  for f in run.txt summary.txt simlog.txt; do [ -s "$results/$f" ] && extra+=(--summary "$results/$f"); done
  if "$HAP_ROOT/userspace/target/release/hapctl" analyze "$results/simlog.bin" --out "$results/plots" \
      "${extra[@]}" > "$results/analysis.log" 2>&1; then
    report="$results/plots/summary.html"
  else
    log "hapctl analyze failed: $(tail -3 "$results/analysis.log")"
  fi
fi
echo
echo "=== demo finished (accelerator: $mode; under TCG timing figures are emulation artefacts)"
grep -E '^(sample_rate_hz|loss_ratio|rtt_ms_mean|coupling_error_mean_m|handle_travel_m|coupled_travel_m):' "$results/summary.txt" 2>/dev/null | sed 's/^/  client  /'
grep -E '^(cycles|misses|max_consecutive_misses|wakeup.p99_us|exec.p99_us|frames_in|answers_sent|state):' "$results/hap_stats.txt" | sed 's/^/  module  /' || true
# The fail-safe that ended the run and its cause (stop_requested: the end of a
# normal run; miss_limit: the guest was starved, see timing.md).
grep -a -m1 -o 'hapticctrl: fail-safe ([a-z_]*): start.*' "$qlog" | tr -d '\r' | sed 's/^/  guest   /' || true
[ "$client_rc" = 0 ] || echo "  client  failed (exit $client_rc): $(grep -a 'error' "$results/client.txt" | tail -1)"
grep -E '^(records|duration_s|dropped_records|misses_located|fail_safe_steps|max_coupling_force_n|max_handle_speed_m_s|felt_stiffness_n_per_mm):' "$results/plots/analysis.txt" 2>/dev/null | sed 's/^/  log     /' || true
# The log's time is the guest's servo time: under TCG it runs slower than the
# client's wall clock, and the plots' time axis is the guest's.
guest_s=$(sed -n 's/^duration_s: *//p' "$results/plots/analysis.txt" 2>/dev/null)
if [ -n "$guest_s" ]; then
  echo "  the log's ${guest_s} s are guest servo time from insmod to the fail-safe (the client ran ${duration} s of wall time)"
fi
echo "results: $results (run.txt, run.csv, summary.txt, hap_stats.txt, hap_hist.txt, proto_interface.txt, simlog.bin, plots/)"
if [ -n "$report" ]; then echo "report: $report"; fi
if [ -n "$cpid" ] && kill -0 "$cpid" 2>/dev/null; then
  echo "the 3D page http://$http/ links to the report for 10 minutes (Ctrl-C ends it)"
  trap 'kill $cpid 2>/dev/null || true' EXIT INT
  wait "$cpid" || true
fi
