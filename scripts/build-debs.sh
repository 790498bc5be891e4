#!/usr/bin/env bash
# Build hapticctrl's two Debian packages with dpkg-deb:
#  - hapticctrl-dkms (all): the module's source under /usr/src/hapticctrl-VER
#    with dkms.conf (packaging/dkms.conf); its pre-build step regenerates the
#    kernel headers' rust/ (scripts/rust-headers.sh), so DKMS builds the module
#    for every installed Rust-enabled kernel, and again after a kernel upgrade;
#  - hapticctrl-tools (amd64): proto_interface, hapctl, hapdev, virtuose_demo,
#    the launch script hapticctrl.sh, the VirtuoseAPI library as
#    scripts/install-virtuose-api.sh installs it (headers VirtuoseAPI.h,
#    virtuoseAPI.h, virtuose_api.h; libvirtuose_api and Haption's names
#    libvirtuose, libVirtuoseAPI, libvirtuoseDLL, virtuoseAPI.so; virtuose.pc;
#    the CMake package VirtuoseAPI), the sample effort sequences
#    (/usr/share/hapticctrl/*.eff).
#   scripts/build-debs.sh [--out DIR]      (default build/debs; prints the two paths)
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
out=$HAP_ROOT/build/debs
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out=$2; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done
VERSION=$(sed -n 's/^version = "\(.*\)"/\1/p' "$HAP_ROOT/userspace/proto_interface/Cargo.toml" | head -1)
[ -n "$VERSION" ] || die "cannot read the version from userspace/proto_interface/Cargo.toml"
MAINT="hapticctrl maintainers <hapticctrl@localhost>"
mkdir -p "$out"
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT

# --- hapticctrl-dkms -------------------------------------------------------
d=$stage/dkms
src=$d/usr/src/hapticctrl-$VERSION
mkdir -p "$src/scripts" "$src/userspace/hap-core" "$d/DEBIAN" "$d/usr/share/doc/hapticctrl-dkms"
cp "$HAP_ROOT/Kbuild" "$HAP_ROOT/Makefile" "$src/"
cp -r "$HAP_ROOT/module" "$src/module"
cp -r "$HAP_ROOT/userspace/hap-core/src" "$src/userspace/hap-core/src"
cp "$HAP_ROOT/scripts/rust-headers.sh" "$HAP_ROOT/scripts/check-ko-symbols.sh" "$src/scripts/"
chmod 755 "$src/scripts/"*.sh
sed "s/@VERSION@/$VERSION/g" "$HAP_ROOT/packaging/dkms.conf" >"$src/dkms.conf"
cat >"$d/DEBIAN/control" <<EOF
Package: hapticctrl-dkms
Version: $VERSION
Architecture: all
Section: kernel
Priority: optional
Maintainer: $MAINT
Depends: dkms, bash, make, kmod, rustc, rust-src, bindgen, libclang-dev, pahole, libssl-dev, openssl, libelf-dev, bc, flex, bison, python3, xz-utils, linux-source-7.3
Recommends: hapticctrl-tools
Description: hapticctrl real-time haptic servo controller, kernel module (DKMS)
 The hapticctrl Rust kernel module, built by DKMS for every installed
 Rust-enabled kernel. Debian's linux-headers ship no Rust metadata: the
 pre-build step regenerates it from linux-source with the kernel's own rustc
 (rustc must be the version in the kernel's RUSTC_VERSION_TEXT).
EOF
cat >"$d/DEBIAN/postinst" <<EOF
#!/bin/sh
set -e
[ "\$1" = configure ] || exit 0
dkms status -m hapticctrl -v $VERSION | grep -q . || dkms add -m hapticctrl -v $VERSION
# Build for every installed kernel whose headers are Rust-enabled. A failure
# is reported, not fatal: fix the toolchain, then run dkms autoinstall.
for h in /usr/src/linux-headers-*; do
  [ -f "\$h/.config" ] && grep -q '^CONFIG_RUST=y' "\$h/.config" || continue
  k=\${h#/usr/src/linux-headers-}
  [ -d "/lib/modules/\$k" ] || continue
  dkms install -m hapticctrl -v $VERSION -k "\$k" ||
    echo "hapticctrl-dkms: the module did not build for \$k (see above); fix, then: dkms install -m hapticctrl -v $VERSION -k \$k" >&2
done
exit 0
EOF
cat >"$d/DEBIAN/prerm" <<EOF
#!/bin/sh
set -e
dkms remove -m hapticctrl -v $VERSION --all >/dev/null 2>&1 || true
exit 0
EOF
chmod 755 "$d/DEBIAN/postinst" "$d/DEBIAN/prerm"
printf 'hapticctrl\nLicense: GPL-2.0-only\n' >"$d/usr/share/doc/hapticctrl-dkms/copyright"
dkms_deb=$out/hapticctrl-dkms_${VERSION}_all.deb
dpkg-deb --root-owner-group -Zxz -b "$d" "$dkms_deb" >/dev/null

# --- hapticctrl-tools ------------------------------------------------------
log "cargo build --release (proto_interface, hapctl, hapdev, virtuose_demo, virtuose_api)"
(cd "$HAP_ROOT/userspace" && cargo build --release --quiet -p proto_interface -p hapctl -p hapdev -p virtuose_demo -p virtuose_api)
rel=$HAP_ROOT/userspace/target/release
t=$stage/tools
mkdir -p "$t/DEBIAN" "$t/usr/bin" "$t/usr/sbin" "$t/usr/lib/x86_64-linux-gnu" "$t/usr/include" "$t/usr/share/doc/hapticctrl-tools"
for b in proto_interface hapctl hapdev virtuose_demo; do install -m 755 "$rel/$b" "$t/usr/bin/$b"; done
install -m 755 "$HAP_ROOT/scripts/hapticctrl.sh" "$t/usr/sbin/hapticctrl.sh"
bash "$HAP_ROOT/scripts/install-virtuose-api.sh" --prefix /usr --libdir lib/x86_64-linux-gnu --destdir "$t" --no-build >/dev/null
mkdir -p "$t/usr/share/hapticctrl"
install -m 644 "$HAP_ROOT"/tests/data/*.eff "$t/usr/share/hapticctrl/"
printf 'hapticctrl\nLicense: GPL-2.0-only\n' >"$t/usr/share/doc/hapticctrl-tools/copyright"
# Depends: the packages (on this machine) of the shared libraries the ELF
# files need, at least at the versions built against.
deps=$(for f in "$t"/usr/bin/* "$t"/usr/lib/x86_64-linux-gnu/*.so*; do [ -L "$f" ] && continue; objdump -p "$f" | awk '/NEEDED/ { print $2 }'; done | sort -u |
  while read -r lib; do
    path=$(ldconfig -p | awk -v l="$lib" '$1 == l && /x86-64/ { print $NF; exit }')
    [ -n "$path" ] || continue
    pkg=$(dpkg -S "$(readlink -f "$path")" 2>/dev/null | head -1 | cut -d: -f1) || true
    [ -n "$pkg" ] || pkg=$(dpkg -S "$path" 2>/dev/null | head -1 | cut -d: -f1) || true
    [ -n "$pkg" ] && echo "$pkg (>= $(dpkg-query -W -f='${Version}' "$pkg" | sed 's/[+~-].*//'))"
  done | sort -u | paste -sd, | sed 's/,/, /g')
cat >"$t/DEBIAN/control" <<EOF
Package: hapticctrl-tools
Version: $VERSION
Architecture: amd64
Section: misc
Priority: optional
Maintainer: $MAINT
Depends: ${deps:-libc6}
Recommends: hapticctrl-dkms
Description: hapticctrl real-time haptic servo controller, userspace tools
 proto_interface (the UDP bridge between clients and the kernel module),
 hapctl (control and analysis), hapdev (device-level tool), virtuose_demo
 (test client), the launch script hapticctrl.sh, and the client library:
 Haption's VirtuoseAPI (headers VirtuoseAPI.h and virtuoseAPI.h, libraries
 libvirtuose, libVirtuoseAPI, libvirtuoseDLL, virtuoseAPI.so, pkg-config
 virtuose, CMake package VirtuoseAPI) and hapticctrl's libvirtuose_api.
EOF
tools_deb=$out/hapticctrl-tools_${VERSION}_amd64.deb
dpkg-deb --root-owner-group -Zxz -b "$t" "$tools_deb" >/dev/null
log "built $dkms_deb and $tools_deb"
echo "$dkms_deb"
echo "$tools_deb"
