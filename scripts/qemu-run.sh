#!/usr/bin/env bash
# Boot the hapticctrl test kernel (or Debian's stock kernel) in QEMU with the
# module and run one in-guest test script; exit with its status. The guest log
# is kept; the guest prints its kernel (HAPTEST-KERNEL `uname -rv`).
#   scripts/qemu-run.sh [options] TEST_SCRIPT [ARG ...]
# Options:
#   --debug             use the debug kernel variant (lockdep, atomic-sleep checks)
#   --kasan             use the KASAN kernel variant (debug + generic KASAN; make KASAN=1)
#   --stock             boot Debian's stock 7.3 rt-amd64 kernel (trixie-backports, its
#                       vmlinuz and virtio-net modules unpacked by scripts/debian-kernel.sh)
#                       with the module built against its headers (make STOCK=1)
#   --icount            deterministic guest time: -icount shift=0,align=off,sleep=off -smp 1
#   --icount-sleep      link-friendly guest time: -icount shift=0,align=off,sleep=on -smp 1
#                       (busy time counted in instructions, idle time follows the host clock)
#   --smp N             vCPUs (default 2; forced to 1 with --icount)
#   --timeout S         kill the guest after S seconds (default 120): a hang fails
#   --udp HOST:GUEST    forward UDP 127.0.0.1:HOST to the guest's port GUEST (repeatable:
#                       one forward per arm's bridge)
#   --ko FILE           boot this hapticctrl.ko instead of build/<variant>/module/
#   --log FILE          keep the guest log there (default build/logs/<test>.log)
#   --extra SRC:DST     add a file to the initramfs (repeatable)
#   --key FILE          install FILE as the bridge's key (/etc/hapticctrl/hap.key)
#   --insecure-bridge   no key: the launch script runs the bridge unauthenticated (v1)
#   --accel tcg|kvm     force the accelerator (default: KVM if a probe boot works)
#   --period-us N       the servo period the in-guest tests use (hap.period_us=N)
#   --background        start the guest and return; prints "PID LOG" (for host-side tests)
# ARGs are passed to the test script (comma-free words).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"

ko=""; variant=""; period_us=""; icount=0; smp=2; timeout_s=120; udp=""; log=""; accel=${HAP_ACCEL:-}; background=0
extras=(); insecure_marker=""; udp_fwds=()
while [ $# -gt 0 ]; do
  case "$1" in
    --debug) variant=debug ;;
    --kasan) variant=kasan ;;
    --stock) variant=stock ;;
    --icount) icount=1 ;;
    --icount-sleep) icount=2 ;;
    --smp) smp=$2; shift ;;
    --timeout) timeout_s=$2; shift ;;
    --udp) udp_fwds+=("$2"); udp=$2; shift ;;
    --log) log=$2; shift ;;
    --ko) ko=$2; shift ;;
    --extra) extras+=("$2"); shift ;;
    --key) [ -f "$2" ] || die "--key $2: no such file"; extras+=("$2:/etc/hapticctrl/hap.key"); shift ;;
    --insecure-bridge) insecure_marker=$(mktemp); extras+=("$insecure_marker:/etc/hapticctrl/insecure") ;;
    --accel) accel=$2; shift ;;
    --background) background=1 ;;
    --period-us) period_us=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    --) shift; break ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) break ;;
  esac
  shift
done
test_script=${1:?usage: qemu-run.sh [options] TEST_SCRIPT [ARG ...] (see --help)}
shift
[ -f "$test_script" ] || die "no such test script: $test_script"
args=$(IFS=,; echo "$*")

ko=${ko:-$HAP_ROOT/build/${variant:-base}/module/hapticctrl.ko}
[ -f "$ko" ] || die "module not built: run 'make$( case "$variant" in debug) echo " DEBUG=1" ;; kasan) echo " KASAN=1" ;; stock) echo " STOCK=1" ;; esac)'"
mem=512
kmod_dir=""; stock_append=""
if [ "$variant" = stock ]; then
  # Debian's kernel: its vmlinuz, and virtio-net with its dependencies from
  # its modules package (decompressed, loaded by /init in dependency order).
  img=$(bash "$HERE/debian-kernel.sh" image)
  krel=$(bash "$HERE/debian-kernel.sh" release)
  kernel_image="$img/boot/vmlinuz-$krel"
  mem=1024
  # The emulated CPU needs no speculation mitigations (the self-built kernel
  # has none compiled in); on, they cost the stock guest ~1/4 of its link rate.
  stock_append="mitigations=off"
  if [ -n "$udp" ]; then
    kmod_dir=$(mktemp -d)
    n=10
    while read -r m; do
      n=$((n + 1))
      case "$m" in
        *.xz) xz -dc "$img/lib/modules/$krel/$m" ;;
        *.zst) zstd -qdc "$img/lib/modules/$krel/$m" ;;
        *) cat "$img/lib/modules/$krel/$m" ;;
      esac >"$kmod_dir/$n-$(basename "${m%.ko*}").ko"
      extras+=("$kmod_dir/$n-$(basename "${m%.ko*}").ko:/lib/modules/boot/$n-$(basename "${m%.ko*}").ko")
    done < <(hap_kmod_order "$img/lib/modules/$krel/modules.dep" virtio_net)
  fi
else
  KDIR=$(bash "$HERE/build-kernel.sh" ${variant:+--$variant})
  kernel_image="$KDIR/arch/x86/boot/bzImage"
fi
name=$(basename "$test_script" .sh)
mkdir -p "$HAP_ROOT/build/logs"
log=${log:-$HAP_ROOT/build/logs/$name${variant:+-$variant}.log}
initrd=$(mktemp --suffix=.cpio.gz)
trap 'rm -f "$initrd" ${insecure_marker:+"$insecure_marker"}; [ -z "$kmod_dir" ] || rm -rf "$kmod_dir"' EXIT
extra_args=()
for e in "${extras[@]+"${extras[@]}"}"; do extra_args+=("$e"); done
bash "$HERE/mkinitramfs.sh" "$initrd" "$ko" "$test_script" "${extra_args[@]+"${extra_args[@]}"}"

# Accelerator: KVM only if a probe boot works on this machine (cached).
probe_kvm() {
  local cache="$HAP_CACHE/kvm-probe-$(uname -r)"
  if [ -f "$cache" ]; then cat "$cache"; return; fi
  local res=tcg
  if [ -w /dev/kvm ]; then
    local pinit; pinit=$(mktemp --suffix=.cpio.gz)
    printf '#!/bin/sh\necho HAP-KVM-PROBE-OK\npoweroff -f\n' >"$pinit.sh"
    bash "$HERE/mkinitramfs.sh" "$pinit" "$ko" "$pinit.sh" 2>/dev/null
    if timeout 25 qemu-system-x86_64 -enable-kvm -cpu host -m 256 -nographic -no-reboot -nodefaults \
        -serial stdio -kernel "$kernel_image" -initrd "$pinit" \
        -append "console=ttyS0 panic=-1 rdinit=/init quiet" 2>/dev/null | grep -q HAP-KVM-PROBE-OK; then
      res=kvm
    fi
    rm -f "$pinit" "$pinit.sh"
  fi
  echo "$res" >"$cache"; echo "$res"
}
[ -n "$accel" ] || accel=$(probe_kvm)
qemu=(qemu-system-x86_64 -m "$mem" -nographic -no-reboot -nodefaults -serial stdio
  -kernel "$kernel_image" -initrd "$initrd")
mode="$accel"
if [ "$accel" = kvm ]; then
  qemu+=(-enable-kvm -cpu host -smp "$smp")
elif [ "$icount" = 1 ]; then
  qemu+=(-accel tcg -icount shift=0,align=off,sleep=off -smp 1); mode="tcg-icount"
elif [ "$icount" = 2 ]; then
  qemu+=(-accel tcg -icount shift=${HAP_ICOUNT_SHIFT:-0},align=off,sleep=on -smp 1); mode="tcg-icount-sleep"
else
  qemu+=(-accel tcg,thread=multi -smp "$smp")
fi
if [ -n "$udp" ]; then
  nic="user,model=virtio-net-pci"
  for f in "${udp_fwds[@]}"; do nic="$nic,hostfwd=udp:127.0.0.1:${f%%:*}-:${f#*:}"; done
  qemu+=(-nic "$nic")
fi
append="console=ttyS0 panic=-1 rdinit=/init loglevel=6 tsc=reliable${stock_append:+ $stock_append} hap.mode=$mode${HAP_APPEND:+ $HAP_APPEND}"
[ -n "$args" ] && append="$append hap.args=$args"
[ -n "$period_us" ] && append="$append hap.period_us=$period_us"
qemu+=(-append "$append" ${HAP_QEMU_EXTRA:-})
log "booting $name (${variant:-base} kernel, accel=$mode${udp:+, udp ${udp_fwds[*]}}); log: $log"

if [ "$background" = 1 ]; then
  trap - EXIT
  ( "${qemu[@]}" >"$log" 2>&1; rm -f "$initrd"; [ -z "$kmod_dir" ] || rm -rf "$kmod_dir" ) &
  echo "$! $log"
  exit 0
fi

start=$(date +%s)
set +e
timeout --foreground -k 5 "$timeout_s" "${qemu[@]}" 2>&1 | tee "$log" | sed -u -n -e '/^HAPTEST/p' -e '/^\(ok\|not ok\|PASS\|FAIL\|#\|--\) /p' -e '/passed, [0-9]* failed/p'
qrc=${PIPESTATUS[0]}
set -e
elapsed=$(( $(date +%s) - start ))
rc=$(sed -n 's/.*HAPTEST-RESULT rc=\([0-9]*\).*/\1/p' "$log" | tail -1)
problems=$(grep -n -E "$HAP_SPLAT_RE" "$log" || true)
if [ "$qrc" = 124 ] || [ "$qrc" = 137 ]; then
  echo "qemu-run: $name TIMED OUT after ${timeout_s}s (accel=$mode). Last lines of $log:" >&2
  tail -40 "$log" >&2; exit 1
fi
if [ -n "$problems" ]; then
  echo "qemu-run: $name: kernel problems in the guest log ($log):" >&2
  echo "$problems" | head -20 >&2
  grep -n -A30 -E 'WARNING:|BUG:|Oops|panic' "$log" | head -80 >&2
  exit 1
fi
if [ -z "$rc" ]; then
  echo "qemu-run: $name: the guest ended without a result (crash?). Last lines of $log:" >&2
  tail -40 "$log" >&2; exit 1
fi
log "$name finished in ${elapsed}s with rc=$rc (accel=$mode)"
exit "$rc"
