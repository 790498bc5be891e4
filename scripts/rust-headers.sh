#!/usr/bin/env bash
# Regenerate the Rust artefacts that Debian's linux-headers packages do not
# ship (rust/*.rmeta, rust/*.so, scripts/target.json), so that out-of-tree
# Rust modules such as hapticctrl can be built against a stock Debian kernel.
# Runs on Debian 13 (or in the trixie chroot of scripts/debian-kernel.sh) as
# root, with the distribution's own toolchain: the exact rustc the kernel was
# built with (its .config's RUSTC_VERSION_TEXT), rust-src, bindgen,
# libclang-dev, the kernel's gcc, pahole, libssl-dev, openssl, and
# linux-source-X.Y of the same upload as the headers.
#
#   scripts/rust-headers.sh [--check] [--install-deps] [KERNELRELEASE]
#
# KERNELRELEASE defaults to the running kernel (uname -r). With --check it
# only says whether the artefacts are there and current (exit 0) or not
# (exit 1). With --install-deps it first installs the toolchain with apt
# (exact versions, nothing upgraded). Idempotent: a stamp in the headers'
# rust/ (headers, source and rustc versions) makes a second run return at
# once. Also the pre-build step of the hapticctrl DKMS package.
#
# Environment: HAP_KWORK (default /var/cache/hapticctrl/kbuild) holds the
# unpacked source while it builds; removed afterwards unless HAP_KEEP_WORK=1.
set -euo pipefail

say() { echo "rust-headers: $*" >&2; }
die() { echo "rust-headers: error: $*" >&2; exit 1; }

check=0; install_deps=0; krel=""
for a in "$@"; do
  case "$a" in
    --check) check=1 ;;
    --install-deps) install_deps=1 ;;
    -h|--help) sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) die "unknown option $a (see --help)" ;;
    *) krel=$a ;;
  esac
done
[ -n "$krel" ] || krel=$(uname -r)
case "$krel" in *[!A-Za-z0-9.+_-]*|'') die "bad kernel release '$krel'" ;; esac

H=/usr/src/linux-headers-$krel
[ -d "$H" ] || H=$(readlink -f "/lib/modules/$krel/build" 2>/dev/null || true)
[ -n "$H" ] && [ -f "$H/.config" ] || die "no headers for $krel: install linux-headers-$krel"
cfg() { sed -n "s/^CONFIG_$1=\"\{0,1\}\([^\"]*\)\"\{0,1\}\$/\1/p" "$H/.config"; }
[ "$(cfg RUST)" = y ] || die "$krel is built without CONFIG_RUST: no Rust module can be built for it"

# Which packages own the headers and the source, at which versions.
hdr_pkg=$(dpkg-query -S "$H/.config" 2>/dev/null | cut -d: -f1 | head -1)
[ -n "$hdr_pkg" ] || die "$H/.config belongs to no package (not a Debian headers tree?)"
hdr_ver=$(dpkg-query -W -f='${Version}' "$hdr_pkg")
kmaj=$(echo "$krel" | cut -d. -f1-2)
src_pkg=linux-source-$kmaj
rustc_want=$(cfg RUSTC_VERSION_TEXT)
rust_up=$(echo "$rustc_want" | sed -n 's/^rustc \([0-9][0-9.]*\).*/\1/p')
cc_text=$(cfg CC_VERSION_TEXT)
cc=${cc_text%% *}
[ -n "$rust_up" ] && [ -n "$cc" ] || die "cannot read RUSTC_VERSION_TEXT / CC_VERSION_TEXT from $H/.config"
gcc_pkg=$(echo "$cc" | sed -n 's/^x86_64-linux-gnu-\(gcc-[0-9]*\)$/\1/p')

# The artefacts and the stamp that says for which versions they were made.
stamp=$H/rust/.hapticctrl-stamp
target_json=$(readlink -f "$H/scripts")/target.json
want_stamp="headers=$hdr_pkg $hdr_ver; rustc=$rustc_want"
current() {
  [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want_stamp" ] &&
    ls "$H"/rust/libkernel.rmeta "$H"/rust/libmacros.so >/dev/null 2>&1 && [ -f "$target_json" ]
}
if current; then
  say "rust/ of $H is current ($want_stamp)"
  exit 0
fi
[ "$check" = 0 ] || { say "rust/ of $H is missing or stale"; exit 1; }
[ "$(id -u)" = 0 ] || die "run as root (it writes into $H)"

# Debian's package version of the kernel's rustc (1.85.1 -> 1.85.1+dfsg1-...).
apt_version() { apt-cache madison "$1" 2>/dev/null | awk -v v="$2" '$3 ~ "^"v"[+~-]" { print $3; exit }'; }
if [ "$install_deps" = 1 ]; then
  export DEBIAN_FRONTEND=noninteractive
  rv=$(apt_version rustc "$rust_up"); sv=$(apt_version rust-src "$rust_up")
  [ -n "$rv" ] && [ -n "$sv" ] || die "apt offers no rustc/rust-src $rust_up (the kernel's compiler); is trixie in the sources?"
  pkgs="rustc=$rv rust-src=$sv bindgen libclang-dev ${gcc_pkg:-gcc} pahole libssl-dev openssl libelf-dev make bc flex bison python3 xz-utils $src_pkg=$hdr_ver"
  say "apt-get install $pkgs"
  # shellcheck disable=SC2086
  plan=$(apt-get -s -y --no-install-recommends install $pkgs 2>&1) || { echo "$plan" >&2; die "apt cannot install the toolchain"; }
  if echo "$plan" | grep -E '^(Remv|Inst [^ ]+ \[)' >&2; then
    die "apt would upgrade or remove installed packages (above); install the toolchain by hand"
  fi
  # shellcheck disable=SC2086
  apt-get install -y -q --no-install-recommends $pkgs >/dev/null
fi

# The toolchain must be the kernel's own: another rustc gives the kernel
# crate another hash (unresolved symbols) and cannot read its metadata.
command -v rustc >/dev/null || die "rustc not installed (apt install rustc=$rust_up+... rust-src, or --install-deps)"
rustc_have=$(rustc --version)
[ "$rustc_have" = "$rustc_want" ] || die "rustc is '$rustc_have' but $krel was built with '$rustc_want' (install that rustc and rust-src, or --install-deps)"
[ -d "$(rustc --print sysroot)/lib/rustlib/src/rust/library/core" ] || die "rust-src for $rust_up is not installed"
command -v bindgen >/dev/null || die "bindgen not installed"
command -v "$cc" >/dev/null || die "$cc not installed (the kernel's compiler: apt install $gcc_pkg)"
command -v pahole >/dev/null || die "pahole not installed"
command -v openssl >/dev/null || die "openssl not installed (the kernel's config depends on it)"
src_ver=$(dpkg-query -W -f='${Version}' "$src_pkg" 2>/dev/null || true)
[ "$src_ver" = "$hdr_ver" ] || die "$src_pkg is '${src_ver:-not installed}' but the headers are $hdr_ver: install $src_pkg=$hdr_ver"
tarball=$(ls /usr/src/"$src_pkg".tar.* 2>/dev/null | head -1)
[ -n "$tarball" ] || die "no /usr/src/$src_pkg.tar.*"
[ -d /proc/self ] || die "/proc is not mounted (objtool needs it)"

work=${HAP_KWORK:-/var/cache/hapticctrl/kbuild}
src=$work/$src_pkg-$src_ver
o=$work/o-$krel
mkdir -p "$work"
t0=$(date +%s)
if [ ! -f "$src/.unpacked" ]; then
  say "unpacking $tarball"
  rm -rf "$src" "$work/$src_pkg"
  tar -C "$work" -xf "$tarball"
  mv "$work/$src_pkg" "$src"
  touch "$src/.unpacked"
fi
rm -rf "$o"; mkdir -p "$o"
cp "$H/.config" "$o/.config"
km() { make -s -C "$src" O="$o" CC="$cc" HOSTCC="$cc" KERNELRELEASE="$krel" "$@"; }
km olddefconfig >/dev/null
# olddefconfig must keep Debian's configuration as it is: a difference means
# another toolchain (rustc, bindgen, libclang, gcc, openssl) than Debian's.
if ! diff -q <(grep -v '^#' "$H/.config" | sort) <(grep -v '^#' "$o/.config" | sort) >/dev/null 2>&1; then
  diff <(grep -v '^#' "$H/.config" | sort) <(grep -v '^#' "$o/.config" | sort) | head -20 >&2 || true
  die "olddefconfig changed $krel's configuration (above): this toolchain is not the one Debian used"
fi
say "make modules_prepare for $krel with $cc and $rustc_have (about 2-3 minutes on 2 cores)"
km -j"$(nproc)" modules_prepare >&2
for f in "$o"/rust/*.rmeta "$o"/rust/*.so; do [ -f "$f" ] || die "modules_prepare made no $f"; done
[ -f "$o/scripts/target.json" ] || die "modules_prepare made no scripts/target.json"
# target.json lives in the kbuild package's scripts/, shared by the flavours
# of one upload: it must not differ between them.
if [ -f "$target_json" ] && ! cmp -s "$target_json" "$o/scripts/target.json"; then
  [ -f "$stamp" ] || die "$target_json exists and differs from $krel's: refusing to overwrite"
fi
mkdir -p "$H/rust"
rm -f "$H"/rust/*.rmeta "$H"/rust/*.so
cp "$o"/rust/*.rmeta "$o"/rust/*.so "$H/rust/"
cp "$o/scripts/target.json" "$target_json"
echo "$want_stamp" >"$stamp"
[ "${HAP_KEEP_WORK:-0}" = 1 ] || rm -rf "$o" "$src"
say "rust/ regenerated for $krel in $(( $(date +%s) - t0 )) s: $(ls "$H"/rust/*.rmeta | wc -l) .rmeta, $(ls "$H"/rust/*.so | wc -l) .so"
