#!/usr/bin/env bash
# Build (or reuse) the hapticctrl test kernel: Debian's linux-source-7.3 with
# scripts/kernel.config (and scripts/kernel-debug.config with --debug) merged
# onto tinyconfig; --kasan adds scripts/kernel-kasan.config on top of the debug
# fragment (generic KASAN, not used by CI). The tree is cached outside the checkout, keyed by the source
# package version and the fragments' hash; prints the build directory on stdout.
#   scripts/build-kernel.sh [--debug | --kasan]
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"

variant=""
for a in "$@"; do
  case "$a" in
    --debug) variant=debug ;;
    --kasan) variant=kasan ;;
    -h|--help) sed -n '2,7p' "$0"; exit 0 ;;
    *) die "unknown argument '$a' (try --help)" ;;
  esac
done

bash "$HERE/setup-toolchain.sh" >&2
KDIR=$(hap_kernel_dir "$variant")
# One build of a cache directory at a time: a second caller waits for the
# first, then reuses its result.
mkdir -p "$(dirname "$KDIR")"
exec 9>"$KDIR.lock"
flock 9
if [ -f "$KDIR/.hap-built" ] && [ -f "$KDIR/arch/x86/boot/bzImage" ]; then
  log "kernel ${variant:-base} reused from cache: $KDIR"
  echo "$KDIR"; exit 0
fi

SRC="$HAP_CACHE/src/linux-source-$HAP_KERNEL_VERSION"
srcver=$(dpkg-query -W -f='${Version}' "linux-source-$HAP_KERNEL_VERSION")
# The source tree is shared by the variants (a base and a debug build may
# run at the same time): unpacked under a lock of its own.
mkdir -p "$(dirname "$SRC")"
exec 8>"$SRC.lock"
flock 8
if [ ! -f "$SRC/.hap-unpacked-$srcver" ]; then
  log "unpacking linux-source-$HAP_KERNEL_VERSION $srcver"
  rm -rf "$SRC"
  tarball=$(ls /usr/src/linux-source-$HAP_KERNEL_VERSION.tar.*)
  tar -C "$(dirname "$SRC")" -xf "$tarball"
  touch "$SRC/.hap-unpacked-$srcver"
fi
flock -u 8

MAKEFLAGS_K=(LLVM="$HAP_LLVM" RUSTC="$HAP_RUSTC" BINDGEN="$HAP_TOOLS/bin/bindgen")
rm -rf "$KDIR"; mkdir -p "$KDIR"
start=$(date +%s)
log "configuring ${variant:-base} kernel in $KDIR"
make -s -C "$SRC" O="$KDIR" "${MAKEFLAGS_K[@]}" tinyconfig >/dev/null
mapfile -t frags < <(hap_kernel_frags "$variant")
(cd "$KDIR" && "$SRC/scripts/kconfig/merge_config.sh" -m -O "$KDIR" "$KDIR/.config" "${frags[@]}" >/dev/null)
make -s -C "$SRC" O="$KDIR" "${MAKEFLAGS_K[@]}" olddefconfig >/dev/null
make -s -C "$SRC" O="$KDIR" "${MAKEFLAGS_K[@]}" rustavailable >&2 || die "the kernel does not accept this Rust toolchain"
# Every option of the fragments must have survived olddefconfig.
for f in "${frags[@]}"; do
  while IFS= read -r line; do
    case "$line" in ''|'#'*) continue ;; esac
    opt=${line%%=*}; want=${line#*=}
    if [ "$want" = n ]; then
      grep -q "^$opt=" "$KDIR/.config" && die "$opt should be off but is on"
    else
      grep -qx "$line" "$KDIR/.config" || die "$line was dropped by olddefconfig (missing dependency?)"
    fi
  done <"$f"
done
log "building the kernel with make -j$(nproc) (about 5-9 minutes cold on 2 cores)"
make -C "$SRC" O="$KDIR" "${MAKEFLAGS_K[@]}" -j"$(nproc)" 2>&1 | stdbuf -oL awk '
  /^  (CC|RUSTC|LD|AR|AS)/ { n++; if (n % 250 == 0) { printf "[kernel] %d objects ... %s\n", n, $2; fflush() } next }
  { print }' >&2
[ "${PIPESTATUS[0]}" = 0 ] || die "kernel build failed"
touch "$KDIR/.hap-built"
log "kernel ${variant:-base} built in $(( $(date +%s) - start )) s: $KDIR"
echo "$KDIR"
