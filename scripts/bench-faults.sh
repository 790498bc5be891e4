#!/usr/bin/env bash
# Fault campaign on the debug kernel (lockdep, atomic-sleep checks; --kasan:
# the KASAN variant on top of it). Not part of CI. Two guest boots:
#  link boot  (--icount-sleep, UDP forward; host client virtuose_demo,
#             in-guest tests/faults/link-guest.sh):
#    (a) client killed (SIGKILL) mid-session: the coupling wrench must fade to
#        0 (link watchdog); the fade is MEASURED from the answers that keep
#        coming to the dead client's socket (tests/faults/answer_watch.py);
#    (b) proto_interface killed (SIGKILL) and restarted: the module keeps its
#        state (cycle counter, power, no fail-safe), a new session opens;
#    (c) rmmod while the client streams at full rate (1 kHz): EBUSY at once while the
#        bridge holds the devices; bridge killed, rmmod at once: clean unload.
#  local boot (--icount, in-guest tests/faults/local-guest.sh, hapdev only):
#    (c') rmmod during in-guest traffic, N times; (d) power off/on cycles under
#    servo; (e) stop (/dev/hap_stop) under load, N times.
# Asserts states and counts and zero kernel splats (lockdep, atomic sleep,
# WARN, BUG, Oops, KASAN, hung task, soft lockup) over both boots; prints the
# timing figures (never asserts them). Reports in build/faults/.
#   scripts/bench-faults.sh [--kasan] [--period-us N] [--power-cycles N]
#                           [--rmmod N] [--stops N] [--only link|local]
# Defaults: servo period 5000 us in the local boot (lockdep makes every lock
# slow, as in the debug QEMU suite) and 10000 us in the link boot (under
# icount sleep=on a loaded host can make the debug guest miss 5 deadlines
# in a row at 5 ms: a legitimate fail-safe that would end the scenarios);
# --period-us sets both. 100 power cycles, 10 rmmods, 3 stops.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
variant=debug; period_us=""; n_power=100; n_rmmod=10; n_stop=3; only=""
need_val() { [ "$2" -ge 2 ] 2>/dev/null || die "$1 needs a value (try --help)"; }
posint() { [[ "$2" =~ ^[1-9][0-9]*$ ]] || die "$1 wants a positive integer, got '$2'"; }
while [ $# -gt 0 ]; do
  case "$1" in
    --kasan) variant=kasan ;;
    --period-us) need_val "$1" $#; posint "$1" "$2"; period_us=$2; shift ;;
    --power-cycles) need_val "$1" $#; posint "$1" "$2"; n_power=$2; shift ;;
    --rmmod) need_val "$1" $#; posint "$1" "$2"; n_rmmod=$2; shift ;;
    --stops) need_val "$1" $#; posint "$1" "$2"; n_stop=$2; shift ;;
    --only) need_val "$1" $#; only=$2; shift
            case "$only" in link|local) ;; *) die "--only wants link or local, got '$only'" ;; esac ;;
    -h|--help) awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done

link_period_us=${period_us:-10000}; local_period_us=${period_us:-5000}
out="$HAP_ROOT/build/faults/$variant-$(date -u +%Y%m%dT%H%M%SZ)"
mkdir -p "$out"
report="$out/report.txt"
exec > >(tee "$report") 2>&1
campaign_start=$(date +%s)
echo "# hapticctrl fault campaign, $variant kernel, period $link_period_us us (link boot) / $local_period_us us (local boot), $(date -u +%FT%TZ), host $(uname -r), $(nproc) CPUs"

# Builds: the kernel variant (cached), the module, the static guest tools, the host client.
[ -f "$(hap_kernel_dir "$variant")/.hap-built" ] || bash "$HERE/build-kernel.sh" "--$variant" >/dev/null
make -s -C "$HAP_ROOT" "$( [ "$variant" = kasan ] && echo KASAN=1 || echo DEBUG=1 )" >/dev/null
bash "$HERE/build-userspace-static.sh"
(cd "$HAP_ROOT/userspace" && cargo build --release --quiet -p virtuose_demo)
demo="$HAP_ROOT/userspace/target/release/virtuose_demo"

SPLATS='Kernel panic|Oops|WARNING:|BUG:|Call Trace|possible (circular|recursive) locking|inconsistent lock state|sleeping function called from invalid context|DEBUG_LOCKS_WARN_ON|general protection fault|KASAN|UBSAN|rust_panic|panicked at|blocked for more than|soft lockup|hung_task'
fails=0
result() { if [ "$1" = 0 ]; then echo "PASS $2"; else echo "FAIL $2"; fails=$((fails + 1)); fi; }

# ---------------------------------------------------------------- link boot
link_boot() {
  local port="" p
  for p in $(shuf -i 48000-48999 -n 50); do
    if python3 -c "import socket,sys; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(('127.0.0.1', $p))" 2>/dev/null; then port=$p; break; fi
  done
  [ -n "$port" ] || die "no free UDP port in 48000-48999"
  local glog="$out/link-guest.log" t0; t0=$(date +%s)
  local qpid
  # Authenticated like the product: the host clients find the key in HAP_KEY_FILE.
  HAP_KEY_FILE=$(hap_keyfile "$HAP_ROOT/build/hap-test.key"); export HAP_KEY_FILE
  read -r qpid _ < <(bash "$HERE/qemu-run.sh" --background "--$variant" --icount-sleep --period-us "$link_period_us" --key "$HAP_KEY_FILE" \
    --udp "$port:5000" --log "$glog" --extra "$HAP_ROOT/tests/data/walk.eff:/data/effort.eff" \
    "$HAP_ROOT/tests/faults/link-guest.sh" "$link_period_us")
  local cpids=()
  # shellcheck disable=SC2317
  cleanup_link() { kill "${cpids[@]}" 2>/dev/null || true; kill "$qpid" 2>/dev/null || true; }
  trap cleanup_link EXIT
  trap 'cleanup_link; exit 130' INT TERM
  # wait_mark MARK SECONDS: the guest printed MARK (fails if qemu died or time ran out).
  wait_mark() {
    local i
    for ((i = 0; i < $2 * 10; i++)); do
      grep -q "$1" "$glog" 2>/dev/null && return 0
      kill -0 "$qpid" 2>/dev/null || break
      sleep 0.1
    done
    echo "# no $1 in the guest log after $2 s; last lines:"; tail -15 "$glog" | sed 's/^/#   /'
    return 1
  }
  client() { # NAME DURATION [ARGS]: virtuose_demo in the background; pid in $cpid
    local name=$1 dur=$2; shift 2
    "$demo" --server "127.0.0.1#$port" --headless --duration "$dur" --results "$out/$name" "$@" >"$out/$name.txt" 2>&1 &
    cpid=$!; cpids+=("$cpid")
  }
  local ok=1 cpid rc
  echo "## link boot: $variant kernel, tcg-icount-sleep, UDP 127.0.0.1:$port -> guest:5000, period $link_period_us us"
  wait_mark HAP-READY 600 || ok=0
  if [ "$ok" = 1 ]; then
    # (a)
    client client-a 3600
    if wait_mark HAP-A-COUPLED 300; then
      sleep 2
      set +e
      python3 "$HAP_ROOT/tests/faults/answer_watch.py" --pid "$cpid" --period-us "$link_period_us" \
        --server-port "$port" --seconds 10 --csv "$out/fade.csv" >"$out/fade.txt" 2>&1
      rc=$?
      set -e
      sed 's/^/# (a) /' "$out/fade.txt"
      result "$rc" "(a) client killed mid-session: the coupling wrench faded to 0 and stayed 0 (answers after the kill)"
      wait "$cpid" 2>/dev/null || true
    else ok=0; fi
    wait_mark HAP-A-DONE 300 || ok=0
  fi
  if [ "$ok" = 1 ]; then
    # (b)
    if wait_mark HAP-B-RESTARTED 120; then
      # At the servo rate (one VPr per period): the slow debug guest keeps
      # up, so the session's frames, its close included, get through.
      client client-b 15 --rate $(( 1000000 / link_period_us > 10 ? 1000000 / link_period_us : 10 ))
      set +e; wait "$cpid"; rc=$?; set -e
      result "$rc" "(b) a new client session through the restarted bridge ran to its end (virtuose_demo exit $rc)"
      grep -E '^(answers|sample_rate_hz|loss_ratio):' "$out/client-b/summary.txt" 2>/dev/null | sed 's/^/# (b) client: /' || true
      wait_mark HAP-B-DONE 300 || ok=0
    else ok=0; fi
  fi
  if [ "$ok" = 1 ]; then
    # (c)
    client client-c 3600
    wait_mark HAP-C-DONE 600 || ok=0
    kill "$cpid" 2>/dev/null || true
  fi
  # The guest powers off after its script; give it the time to.
  local i
  for ((i = 0; i < 600; i++)); do kill -0 "$qpid" 2>/dev/null || break; sleep 0.1; done
  cleanup_link; trap - EXIT INT TERM
  grep -E '^(ok|not ok|#) ' "$glog" | tr -d '\r' | sed 's/^/  guest: /'
  local grc; grc=$(sed -n 's/.*HAPTEST-RESULT rc=\([0-9]*\).*/\1/p' "$glog" | tail -1)
  result "$([ "${grc:-x}" = 0 ] && echo 0 || echo 1)" "link boot: guest checks (rc=${grc:-none})"
  local splats; splats=$(grep -n -E "$SPLATS" "$glog" || true)
  result "$([ -z "$splats" ] && echo 0 || echo 1)" "link boot: no kernel splat in the guest log${splats:+: $(echo "$splats" | head -5)}"
  echo "# link boot wall time: $(( $(date +%s) - t0 )) s (log $glog)"
}

# ---------------------------------------------------------------- local boot
local_boot() {
  local t0; t0=$(date +%s)
  echo "## local boot: $variant kernel, tcg-icount, period $local_period_us us: $n_rmmod rmmod, $n_power power cycles, $n_stop stops"
  set +e
  bash "$HERE/qemu-run.sh" "--$variant" --icount --period-us "$local_period_us" --timeout 5400 \
    --log "$out/local-guest.log" "$HAP_ROOT/tests/faults/local-guest.sh" "$n_rmmod" "$n_power" "$n_stop" >"$out/local-run.txt" 2>&1
  local rc=$?
  set -e
  sed 's/^/  guest: /' "$out/local-run.txt"
  result "$rc" "local boot: guest checks and qemu-run's splat scan (rc=$rc)"
  local splats; splats=$(grep -n -E "$SPLATS" "$out/local-guest.log" || true)
  result "$([ -z "$splats" ] && echo 0 || echo 1)" "local boot: no kernel splat in the guest log${splats:+: $(echo "$splats" | head -5)}"
  echo "# local boot wall time: $(( $(date +%s) - t0 )) s (log $out/local-guest.log)"
}

[ "$only" = local ] || link_boot
[ "$only" = link ] || local_boot
echo "# campaign wall time: $(( $(date +%s) - campaign_start )) s; report $report"
if [ "$fails" = 0 ]; then echo "faults: all passed ($variant kernel)"; else echo "faults: $fails FAILED ($variant kernel)"; fi
[ "$fails" = 0 ]
