#!/usr/bin/env bash
# Build hapticctrl against Debian's stock Linux 7.3 kernel (trixie-backports,
# CONFIG_RUST=y, built with gcc-14 and rustc 1.85.1), whose headers ship no
# rust/ artefacts. Two ways:
#  - here (any Debian machine, root): a trixie chroot made with debootstrap
#    from Debian's packages, cached in ~/.cache/hapticctrl/debian, holds the
#    kernel's headers and Debian's exact toolchain; scripts/rust-headers.sh
#    regenerates rust/ in it; the module is built in it.
#  - --host, on a Debian 13 machine running that kernel: the same directly on
#    the running system (apt installs the toolchain; nothing is upgraded).
#
#   scripts/debian-kernel.sh [--flavour rt-amd64|amd64] [COMMAND]
# Commands:
#   prepare      chroot, packages, rust/ for the headers (cached); the default
#   build        prepare, then build build/stock/module/hapticctrl.ko
#                (build/stock-amd64/... for --flavour amd64) in the chroot
#   image        extract the kernel image and modules packages (vmlinuz,
#                virtio-net); prints the directory (boot/, lib/modules/)
#   run CMD ...  run CMD in the chroot (/proc mounted, the checkout at its own path)
#   path         print the chroot's path
#   release      print the kernel release (7.3.4+deb13-rt-amd64)
#   --host       on Debian 13: regenerate rust/ for the running kernel
#                (rust-headers.sh --install-deps) and build the module with
#                make KDIR=/lib/modules/$(uname -r)/build
# Cold here: debootstrap ~4 min, packages ~2 min, rust/ ~3 min (2 cores).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"

# The stock kernel: one upload of trixie-backports. A new upload changes the
# release (the ABI name) and these two lines.
DEB_ABI=7.3.4+deb13
DEB_KVERSION=7.3.4-1~bpo13+1
DEB_MIRROR=${HAP_DEBIAN_MIRROR:-http://deb.debian.org/debian}
CHROOT_STAMP=1 # bump when the chroot's package list changes
CHROOT_PKGS=(ca-certificates kmod xz-utils cpio make binutils dkms fakeroot)

flavour=rt-amd64; cmd=prepare
while [ $# -gt 0 ]; do
  case "$1" in
    --flavour) flavour=$2; shift ;;
    --host) cmd=host ;;
    -h|--help) hap_usage; exit 0 ;;
    prepare|build|image|path|release) cmd=$1 ;;
    run) cmd=run; shift; break ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done
case "$flavour" in rt-amd64|amd64) ;; *) die "--flavour is rt-amd64 or amd64" ;; esac
cmd_args=("$@")
KREL=$DEB_ABI-$flavour
DEB_CACHE=$HAP_CACHE/debian
C=$DEB_CACHE/trixie
HDR=/usr/src/linux-headers-$KREL
MO_DIR=$HAP_ROOT/build/stock$([ "$flavour" = rt-amd64 ] || echo "-$flavour")

if [ "$cmd" = release ]; then echo "$KREL"; exit 0; fi
if [ "$cmd" = path ]; then echo "$C"; exit 0; fi

if [ "$cmd" = host ]; then
  # The user's own Debian 13 machine, running the kernel to build for.
  krel=$(uname -r)
  [ -f /etc/debian_version ] && grep -q '^13\|^trixie' /etc/debian_version ||
    die "--host is for a Debian 13 (trixie) machine; elsewhere use the chroot (no --host)"
  [ "$(id -u)" = 0 ] || die "run as root (sudo): it installs packages and writes into the headers"
  dpkg-query -W -f='${Status}' "linux-headers-$krel" 2>/dev/null | grep -q 'install ok installed' ||
    apt-get install -y --no-install-recommends "linux-headers-$krel"
  bash "$HERE/rust-headers.sh" --install-deps "$krel"
  make -C "$HAP_ROOT" KDIR="/lib/modules/$krel/build"
  exit 0
fi

IMG_DIR=$DEB_CACHE/image-$KREL-${DEB_KVERSION//[^A-Za-z0-9.+-]/_}
# An unpacked image needs no lock (QEMU runs ask for it while the chroot may be busy).
if [ "$cmd" = image ] && [ -f "$IMG_DIR/.hap-unpacked" ]; then echo "$IMG_DIR"; exit 0; fi

if [ "$(id -u)" != 0 ]; then
  # debootstrap, chroot and mount need root: through sudo, same cache.
  command -v sudo >/dev/null || die "the chroot needs root (debootstrap, chroot, mount)"
  exec sudo HAP_CACHE="$HAP_CACHE" bash "$0" --flavour "$flavour" "$cmd" ${cmd_args[@]+"${cmd_args[@]}"}
fi
mkdir -p "$DEB_CACHE"
# One user of the chroot at a time.
exec 9>"$DEB_CACHE/lock"
flock 9

# Mounts inside the chroot, undone on exit. The checkout is bind-mounted at
# its own path so that paths read the same inside and out.
mounted=()
umount_all() {
  local i
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount "${mounted[$i]}" 2>/dev/null || umount -l "${mounted[$i]}" || true; done
  mounted=()
}
trap umount_all EXIT
mount_chroot() {
  [ ${#mounted[@]} = 0 ] || return 0
  mountpoint -q "$C/proc" || { mount -t proc proc "$C/proc"; mounted+=("$C/proc"); }
  mkdir -p "$C$HAP_ROOT"
  mountpoint -q "$C$HAP_ROOT" || { mount --bind "$HAP_ROOT" "$C$HAP_ROOT"; mounted+=("$C$HAP_ROOT"); }
  cp -L /etc/resolv.conf "$C/etc/resolv.conf" 2>/dev/null || true
}
in_chroot() { mount_chroot; chroot "$C" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 DEBIAN_FRONTEND=noninteractive "$@"; }
# Remove a chroot directory only when nothing is mounted below it.
safe_rm_chroot() {
  if grep -q " $1/" /proc/mounts; then die "something is still mounted below $1; not removing it"; fi
  rm -rf --one-file-system "$1"
}

# 1. debootstrap (Debian's own, unpacked from its .deb into the cache).
make_base() {
  [ -f "$C/.hap-base" ] && return 0
  local t0; t0=$(date +%s)
  local dbs=$DEB_CACHE/debootstrap
  if [ ! -x "$dbs/usr/sbin/debootstrap" ]; then
    log "fetching debootstrap (apt-get download)"
    rm -rf "$dbs" "$DEB_CACHE/dl"; mkdir -p "$DEB_CACHE/dl"
    (cd "$DEB_CACHE/dl" && apt-get download -q -o APT::Sandbox::User=root debootstrap >/dev/null) || die "apt-get download debootstrap failed"
    dpkg-deb -x "$DEB_CACHE"/dl/debootstrap_*.deb "$dbs"
  fi
  [ -e "$dbs/usr/share/debootstrap/scripts/trixie" ] || die "this debootstrap does not know trixie"
  safe_rm_chroot "$C"
  log "debootstrap trixie (minbase) into $C (about 4 minutes)"
  DEBOOTSTRAP_DIR=$dbs/usr/share/debootstrap "$dbs/usr/sbin/debootstrap" --variant=minbase \
    --keyring=/usr/share/keyrings/debian-archive-keyring.gpg trixie "$C" "$DEB_MIRROR" >"$DEB_CACHE/debootstrap.log" 2>&1 ||
    { tail -20 "$DEB_CACHE/debootstrap.log" >&2; die "debootstrap failed (log: $DEB_CACHE/debootstrap.log)"; }
  cat >"$C/etc/apt/sources.list.d/debian.sources" <<EOF
Types: deb
URIs: $DEB_MIRROR
Suites: trixie trixie-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
  rm -f "$C/etc/apt/sources.list"
  # No daemons start in the chroot.
  printf '#!/bin/sh\nexit 101\n' >"$C/usr/sbin/policy-rc.d"; chmod +x "$C/usr/sbin/policy-rc.d"
  touch "$C/.hap-base"
  log "TIMING debootstrap $(( $(date +%s) - t0 )) s"
}

# 2. Packages: the headers and source of the stock kernel, then Debian's
# exact toolchain for it (rust-headers.sh --install-deps reads the versions
# from the headers' .config).
pkg_stamp() { echo "$CHROOT_STAMP ${CHROOT_PKGS[*]} $KREL $DEB_KVERSION"; }
install_pkgs() {
  local st="$C/.hap-pkgs-$flavour"
  [ -f "$st" ] && [ "$(cat "$st")" = "$(pkg_stamp)" ] && return 0
  local t0; t0=$(date +%s)
  log "apt in the chroot: linux-headers-$KREL $DEB_KVERSION, linux-source-7.3, ${CHROOT_PKGS[*]}"
  in_chroot apt-get update -q -o Acquire::Retries=3 >/dev/null
  in_chroot apt-get install -y -q --no-install-recommends -o Acquire::Retries=3 "${CHROOT_PKGS[@]}" \
    "linux-headers-$KREL=$DEB_KVERSION" "linux-source-7.3=$DEB_KVERSION" >/dev/null
  log "TIMING chroot packages (headers, source, tools) $(( $(date +%s) - t0 )) s"
  pkg_stamp >"$st"
}

prepare() {
  make_base
  install_pkgs
  if ! in_chroot bash "$HAP_ROOT/scripts/rust-headers.sh" --check "$KREL" 2>/dev/null; then
    local t0; t0=$(date +%s)
    # The unpacked source and the build (~3 GB, thrown away afterwards) in
    # memory: unpacking and removing 80 000 files is slow on a busy disk.
    local kw=$C/var/cache/hapticctrl/kbuild
    mkdir -p "$kw"
    if ! mountpoint -q "$kw" && [ "${HAP_KBUILD_TMPFS:-1}" = 1 ]; then
      mount -t tmpfs -o size=8g hap-kbuild "$kw" && mounted+=("$kw")
    fi
    in_chroot bash "$HAP_ROOT/scripts/rust-headers.sh" --install-deps "$KREL" ||
      die "regenerating rust/ for $KREL failed"
    log "TIMING toolchain + rust/ regeneration (modules_prepare) $(( $(date +%s) - t0 )) s"
  fi
}

build() {
  prepare
  local t0; t0=$(date +%s)
  mkdir -p "$MO_DIR"
  in_chroot make -s -C "$HAP_ROOT" KDIR="$HDR" MO="$MO_DIR" module >&2 || die "module build against $KREL failed"
  log "TIMING module build against $KREL $(( $(date +%s) - t0 )) s: $MO_DIR/module/hapticctrl.ko"
}

# The kernel image and its modules, unpacked (not installed) from the image
# packages: QEMU boots boot/vmlinuz-*, the initramfs takes virtio-net from
# lib/modules/.
image() {
  local dir=$IMG_DIR
  if [ ! -f "$dir/.hap-unpacked" ]; then
    make_base
    local t0; t0=$(date +%s)
    log "fetching linux-binary/linux-modules-$KREL $DEB_KVERSION"
    rm -rf "$dir" "$C/var/cache/hap-image"; mkdir -p "$C/var/cache/hap-image" "$dir"
    mount_chroot
    in_chroot apt-get update -q -o Acquire::Retries=3 >/dev/null
    in_chroot sh -c "cd /var/cache/hap-image && apt-get download -q -o APT::Sandbox::User=root 'linux-binary-$KREL=$DEB_KVERSION' 'linux-modules-$KREL=$DEB_KVERSION'" >/dev/null
    for d in "$C"/var/cache/hap-image/*.deb; do dpkg-deb -x "$d" "$dir"; done
    rm -rf "$C/var/cache/hap-image"
    # Newer packages put everything under usr/lib/modules/KREL/ (vmlinuz too).
    if [ -d "$dir/usr/lib/modules" ] && [ ! -e "$dir/lib" ]; then ln -s usr/lib "$dir/lib"; fi
    if [ ! -e "$dir/boot/vmlinuz-$KREL" ] && [ -f "$dir/lib/modules/$KREL/vmlinuz" ]; then
      mkdir -p "$dir/boot"; ln -s "../lib/modules/$KREL/vmlinuz" "$dir/boot/vmlinuz-$KREL"
    fi
    [ -f "$dir/boot/vmlinuz-$KREL" ] || die "no vmlinuz for $KREL in the image packages"
    depmod -b "$dir" "$KREL" || die "depmod of the unpacked modules failed"
    [ -s "$dir/lib/modules/$KREL/modules.dep" ] || die "no modules.dep for $KREL"
    touch "$dir/.hap-unpacked"
    log "TIMING image packages $(( $(date +%s) - t0 )) s"
  fi
  echo "$dir"
}

case "$cmd" in
  prepare) prepare; echo "$C$HDR" ;;
  build) build; echo "$MO_DIR/module/hapticctrl.ko" ;;
  image) image ;;
  run) [ -d "$C/usr" ] || prepare; in_chroot "$@" ;;
esac
