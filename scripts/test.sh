#!/usr/bin/env bash
# Run all of hapticctrl's tests: set-up (idempotent), host tests (cargo test,
# fmt, clippy), the module build with its symbol check, and the QEMU suite.
# Prints "N passed, N failed" per part and a total at the end.
#   scripts/test.sh [--host-only | --qemu-only] [--no-debug-kernel] [--no-e2e]
#                   [--no-debian] [--self-built-kernel]
# The QEMU suite, ViSP's Virtuose test program, the e2e link and (as root)
# the authentication campaign boot Debian's stock 7.3 rt-amd64 kernel with
# the module built against its headers (trixie chroot, scripts/debian-kernel.sh);
# --self-built-kernel boots the project's test kernel instead. The debug-kernel
# suite (lockdep, atomic-sleep) always runs on the self-built debug kernel,
# which also proves that the module builds with the self-built kernels'
# toolchain. The Debian part (tests/debian/packages.sh) builds the DKMS and
# tools packages and installs them in the chroot.
set -uo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
cd "$HAP_ROOT"

host=1; qemu=1; debug=1; e2e=1; debian=1; kernel=stock
for a in "$@"; do
  case "$a" in
    --host-only) qemu=0 ;;
    --qemu-only) host=0 ;;
    --no-debug-kernel) debug=0 ;;
    --no-e2e) e2e=0 ;;
    --no-debian) debian=0 ;;
    --self-built-kernel) kernel=self ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$a' (try --help)" ;;
  esac
done

t_start=$(date +%s)
total_pass=0; total_fail=0; parts=()
# add PART PASSED FAILED (a part that printed no counts counts as one failure)
add() { local p=${2:-0} f=${3:-}; [ -n "$f" ] || f=1; total_pass=$((total_pass + p)); total_fail=$((total_fail + f)); parts+=("$1: $p passed, $f failed"); }

bash "$HERE/setup-toolchain.sh" || die "toolchain set-up failed"

if [ "$host" = 1 ]; then
  log "host tests: cargo test --workspace (userspace/)"
  out=$(mktemp)
  (cd userspace && cargo test --workspace --no-fail-fast --color never 2>&1) | tee "$out"
  rc=${PIPESTATUS[0]}
  p=$(grep -E '^test result:' "$out" | sed -E 's/.* ([0-9]+) passed; ([0-9]+) failed.*/\1/' | paste -sd+ | bc)
  f=$(grep -E '^test result:' "$out" | sed -E 's/.* ([0-9]+) passed; ([0-9]+) failed.*/\2/' | paste -sd+ | bc)
  p=${p:-0}; f=${f:-0}
  [ "$rc" != 0 ] && [ "$f" = 0 ] && f=1
  add "cargo test" "$p" "$f"
  rm -f "$out"

  lint_p=0; lint_f=0
  if (cd userspace && cargo fmt --all -- --check); then lint_p=$((lint_p + 1)); else lint_f=$((lint_f + 1)); echo "FAIL: cargo fmt --check"; fi
  if (cd userspace && cargo clippy --workspace --all-targets --color never -q -- -D warnings); then lint_p=$((lint_p + 1)); else lint_f=$((lint_f + 1)); echo "FAIL: cargo clippy -D warnings"; fi
  if make -s rustfmtcheck >/dev/null; then lint_p=$((lint_p + 1)); else lint_f=$((lint_f + 1)); echo "FAIL: rustfmt --check on module/"; fi
  add "lint" "$lint_p" "$lint_f"

  out=$(mktemp)
  bash tests/host/check-ko-symbols.sh 2>&1 | tee "$out"
  line=$(grep -E 'self-test: [0-9]+ passed' "$out" | tail -1)
  add "symbol check self-test" "$(echo "$line" | sed -E 's/.*: ([0-9]+) passed, ([0-9]+) failed.*/\1/')" "$(echo "$line" | sed -E 's/.*: ([0-9]+) passed, ([0-9]+) failed.*/\2/')"
  log "ViSP's vpVirtuose and Virtuose test programs, unchanged, against the fake controller"
  bash tests/visp/run.sh --target fake 2>&1 | tee "$out"
  line=$(grep -E '^visp-fake: [0-9]+ passed' "$out" | tail -1)
  add "ViSP on VirtuoseAPI.h (fake controller)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
  log "VirtuoseAPI applications' include, library names and calls (tests/vapi/apps.c) against the installed layout"
  t_vapi=$(date +%s)
  bash tests/vapi/run.sh 2>&1 | tee "$out"
  line=$(grep -E '^vapi-apps: [0-9]+ passed' "$out" | tail -1)
  add "VirtuoseAPI applications' conventions (installed layout, fake controller, $(( $(date +%s) - t_vapi )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
  log "Python package: wheel, import, pytest (fake controller, MuJoCo example)"
  rm -f "$out"; out=$(mktemp); t_py=$(date +%s)
  bash tests/python/run.sh 2>&1 | tee "$out"
  line=$(grep -E '^python: [0-9]+ passed' "$out" | tail -1)
  add "Python package (pytest, fake controller, $(( $(date +%s) - t_py )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
  log "hapticctrl-ros2 against Cyclone DDS (Python) as a ROS 2 peer, fake controller"
  rm -f "$out"; out=$(mktemp); t_ros2=$(date +%s)
  bash tests/ros2/run.sh --target fake 2>&1 | tee "$out"
  line=$(grep -E '^ros2-fake: [0-9]+ passed' "$out" | tail -1)
  add "ROS 2 node vs Cyclone DDS (fake controller, $(( $(date +%s) - t_ros2 )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
  rm -f "$out"
fi

if [ "$qemu" = 1 ]; then
  build_p=0; build_f=0
  # The debug kernel is only needed at the end, by the debug suite; on a
  # cold cache it takes ~20 min to build, so it is built in the background,
  # niced, while the stock-kernel parts use mostly one core (QEMU's TCG). The
  # debug part's own build-kernel.sh call waits for it (the cache's lock)
  # and reuses the result. Guest-visible timing is unaffected: the timing-
  # sensitive guests run under icount.
  debug_build_pid=""
  if [ "$debug" = 1 ]; then
    debug_build_log="$HAP_ROOT/build/logs/debug-kernel-build.log"
    mkdir -p "$(dirname "$debug_build_log")"
    nice -n 10 bash "$HERE/build-kernel.sh" --debug >"$debug_build_log" 2>&1 &
    debug_build_pid=$!
    log "building the debug kernel in the background (log: $debug_build_log)"
  fi
  kflag=""
  if [ "$kernel" = stock ]; then
    kflag=--stock
    log "Debian's stock kernel: trixie chroot, rust/ for its headers (cached), the module against them"
    if make -s STOCK=1; then build_p=$((build_p + 1)); else build_f=$((build_f + 1)); echo "FAIL: module build against the stock kernel"; fi
    if bash "$HERE/debian-kernel.sh" image >/dev/null; then build_p=$((build_p + 1)); else build_f=$((build_f + 1)); echo "FAIL: stock kernel image"; fi
  else
    log "building the test kernel (cached) and the module"
    bash "$HERE/build-kernel.sh" >/dev/null || { echo "FAIL: kernel build"; build_f=$((build_f + 1)); }
    if make -s; then build_p=$((build_p + 1)); else build_f=$((build_f + 1)); echo "FAIL: module build or symbol check"; fi
  fi
  if bash "$HERE/build-userspace-static.sh"; then build_p=$((build_p + 1)); else build_f=$((build_f + 1)); echo "FAIL: static userspace build"; fi
  if (cd userspace && cargo build --release --quiet -p virtuose_demo -p hapctl); then build_p=$((build_p + 1)); else build_f=$((build_f + 1)); echo "FAIL: host release build"; fi
  add "build" "$build_p" "$build_f"
  if [ "$build_f" = 0 ]; then
    out=$(mktemp)
    bash tests/run-qemu-suite.sh $kflag | tee "$out"
    line=$(grep -E '^qemu: [0-9]+ passed' "$out" | tail -1)
    add "qemu suite ($kernel kernel)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
    rm -f "$out"
    log "ViSP's vpVirtuose and testVirtuoseHapticBox, unchanged, against the module in QEMU"
    out=$(mktemp); t_visp=$(date +%s)
    bash tests/visp/run.sh --target qemu $([ "$kernel" = self ] && echo --self-built-kernel) 2>&1 | tee "$out"
    line=$(grep -E '^visp-qemu: [0-9]+ passed' "$out" | tail -1)
    add "ViSP on VirtuoseAPI.h (module in QEMU, $kernel kernel, $(( $(date +%s) - t_visp )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
    rm -f "$out"
    if [ "$kernel" = stock ]; then
      log "the Python package's MuJoCo example against the module in QEMU"
      out=$(mktemp); t_pyq=$(date +%s)
      bash tests/python/run.sh --target qemu 2>&1 | tee "$out"
      line=$(grep -E '^python-qemu: [0-9]+ passed' "$out" | tail -1)
      add "Python MuJoCo example (module in QEMU, $(( $(date +%s) - t_pyq )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      rm -f "$out"
    fi
    log "hapticctrl-ros2 against Cyclone DDS (Python) as a ROS 2 peer, module in QEMU"
    out=$(mktemp); t_ros2=$(date +%s)
    bash tests/ros2/run.sh --target qemu $([ "$kernel" = self ] && echo --self-built-kernel) 2>&1 | tee "$out"
    line=$(grep -E '^ros2-qemu: [0-9]+ passed' "$out" | tail -1)
    add "ROS 2 node vs Cyclone DDS (module in QEMU, $kernel kernel, $(( $(date +%s) - t_ros2 )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
    rm -f "$out"
    if [ "$e2e" = 1 ]; then
      out=$(mktemp)
      bash tests/e2e/link.sh $kflag | tee "$out"
      line=$(grep -E '^e2e: [0-9]+ passed' "$out" | tail -1)
      add "host<->guest e2e link ($kernel kernel)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      # Two arms, two clients at once (one UDP port per arm).
      t_arms=$(date +%s)
      bash tests/e2e/two-arms.sh $kflag | tee "$out"
      line=$(grep -E '^e2e-arms: [0-9]+ passed' "$out" | tail -1)
      add "host<->guest e2e, two arms and two clients ($kernel kernel, $(( $(date +%s) - t_arms )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      # A slow link (300 ms round trip, ±50 % jitter, 10 % loss) through
      # the link emulator, the client keeping the link passive and not
      # pacing its frames (a late target stays passive; pacing on the
      # answers left the module's VPr up to ~100 ms apart as the stream
      # started, at the watchdog's limit).
      t_netem=$(date +%s)
      bash tests/e2e/netem.sh $kflag --link-passivity --client-window 0 | tee "$out"
      line=$(grep -E '^e2e-netem: [0-9]+ passed' "$out" | tail -1)
      add "host<->guest e2e, slow link through the emulator ($kernel kernel, $(( $(date +%s) - t_netem )) s)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      # The forged-traffic campaign sends spoofed datagrams from a raw
      # socket: root only.
      if [ "$(id -u)" = 0 ]; then
        bash tests/e2e/auth.sh $kflag | tee "$out"
        line=$(grep -E '^e2e-auth: [0-9]+ passed' "$out" | tail -1)
        add "host<->guest e2e authentication ($kernel kernel)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      else
        echo "SKIP: tests/e2e/auth.sh (spoofs datagrams from a raw socket: needs root)"
      fi
      rm -f "$out"
    fi
    if [ "$debian" = 1 ] && [ "$kernel" = stock ]; then
      out=$(mktemp)
      bash tests/debian/packages.sh | tee "$out"
      line=$(grep -E '^debian: [0-9]+ passed' "$out" | tail -1)
      add "debian packages (dkms, tools, signing)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
      rm -f "$out"
    fi
    if [ "$debug" = 1 ]; then
      [ -z "$debug_build_pid" ] || wait "$debug_build_pid" || tail -20 "$debug_build_log"
      if bash "$HERE/build-kernel.sh" --debug >/dev/null && make -s DEBUG=1; then
        out=$(mktemp)
        bash tests/run-qemu-suite.sh --debug | tee "$out"
        line=$(grep -E '^qemu: [0-9]+ passed' "$out" | tail -1)
        add "qemu suite (debug kernel)" "$(echo "$line" | awk '{print $2}')" "$(echo "$line" | awk '{print $4}')"
        rm -f "$out"
      else
        add "debug build" 0 1
      fi
    fi
  fi
fi

# (A background debug-kernel build not waited for above: the QEMU parts
# were skipped after a failed build.)
[ -z "${debug_build_pid:-}" ] || wait "$debug_build_pid" 2>/dev/null
echo
echo "=== hapticctrl test summary ($(( $(date +%s) - t_start )) s)"
for p in "${parts[@]}"; do echo "  $p"; done
echo "all: $total_pass passed, $total_fail failed"
[ "$total_fail" = 0 ]
