#!/usr/bin/env bash
# Debian packaging on Debian's stock 7.3 rt-amd64 kernel, in the trixie chroot
# of scripts/debian-kernel.sh (which holds that kernel's headers and Debian's
# toolchain): scripts/build-debs.sh builds hapticctrl-dkms and
# hapticctrl-tools; apt installs both in the chroot; DKMS regenerates rust/
# (pre-build) and builds, signs and installs the module for the stock
# headers; the tools run; the DKMS-built module boots in QEMU on that very
# kernel (tests/qemu/01-skeleton.sh); module.sig_enforce=1 refuses the
# unsigned module and one signed with an unenrolled key
# (scripts/sign-module.sh); purging the packages removes the module. The
# chroot is left as it was. Prints "debian: N passed, N failed".
#   tests/debian/packages.sh
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
check() { local d=$1; shift; local o; if o=$("$@" 2>&1); then ok "$d"; else nok "$d: $(echo "$o" | tail -5)"; fi; }
DK=$ROOT/scripts/debian-kernel.sh
krel=$(bash "$DK" release)
C=$(bash "$DK" path)
in_chroot() { bash "$DK" run "$@"; }
work=$ROOT/build/debian-test
rm -rf "$work"; mkdir -p "$work"

bash "$DK" prepare >/dev/null || { nok "the trixie chroot with $krel's headers and rust/"; echo "debian: $pass passed, $fail failed"; exit 1; }
mapfile -t debs < <(bash "$ROOT/scripts/build-debs.sh" --out "$work")
if [ ${#debs[@]} = 2 ] && [ -f "${debs[0]}" ] && [ -f "${debs[1]}" ]; then ok "build-debs.sh built $(basename "${debs[0]}") and $(basename "${debs[1]}")"; else
  nok "build-debs.sh"; echo "debian: $pass passed, $fail failed"; exit 1; fi
ver=$(dpkg-deb -f "${debs[0]}" Version)
check "the dkms package holds dkms.conf with the rust/ pre-build step" sh -c "dpkg-deb --fsys-tarfile '${debs[0]}' | tar -xO ./usr/src/hapticctrl-$ver/dkms.conf | grep -q '^PRE_BUILD=\"scripts/rust-headers.sh'"
check "the tools package holds proto_interface, hapctl, hapdev, virtuose_demo, hapticctrl.sh, libvirtuose_api" sh -c "dpkg-deb -c '${debs[1]}' | grep -c -E '/usr/bin/(proto_interface|hapctl|hapdev|virtuose_demo)$|/usr/sbin/hapticctrl.sh$|libvirtuose_api.so$|virtuose_api.h$' | grep -qx 7"
check "the tools package holds VirtuoseAPI.h, virtuoseAPI.h and Haption's library names, virtuose.pc, the CMake package" sh -c "dpkg-deb -c '${debs[1]}' | grep -c -E '/usr/include/(VirtuoseAPI|virtuoseAPI).h$|/usr/lib/x86_64-linux-gnu/(libvirtuose.so|libvirtuose.so.4|libVirtuoseAPI.so|libVirtuoseAPI.so.4|libvirtuoseDLL.so|libvirtuoseDLL.so.4|virtuoseAPI.so|libvirtuose.a|pkgconfig/virtuose.pc|cmake/VirtuoseAPI/VirtuoseAPIConfig.cmake)( ->|$)' | grep -qx 12"
check "the tools package holds <virtuose/virtuoseAPI.h> and CHAI3D's layout (lib/lin-x86_64/virtuoseAPI.so)" sh -c "dpkg-deb -c '${debs[1]}' | grep -c -E '/usr/include/virtuose/(VirtuoseAPI|virtuoseAPI).h$|/usr/lib/lin-x86_64/virtuoseAPI.so -> ' | grep -qx 3"

# Install both in the chroot (the test removes them again at the end).
mkdir -p "$C/tmp/hap-debs"; cp "${debs[@]}" "$C/tmp/hap-debs/"
in_chroot apt-get install -y -q --no-install-recommends /tmp/hap-debs/"$(basename "${debs[0]}")" /tmp/hap-debs/"$(basename "${debs[1]}")" >"$work/apt-install.log" 2>&1
rc=$?
[ "$rc" = 0 ] && ok "apt installs both packages in the trixie chroot" || nok "apt install (exit $rc): $(tail -15 "$work/apt-install.log")"
status=$(in_chroot dkms status -m hapticctrl 2>&1)
echo "# dkms status: $status"
echo "$status" | grep -q "hapticctrl/$ver, $krel, x86_64: installed" && ok "dkms built and installed the module for $krel" || nok "dkms status: $status; $(grep -iE 'error|fail' "$work/apt-install.log" | head -10)"
kofile=$(cd "$C" && ls lib/modules/"$krel"/updates/dkms/hapticctrl.ko* 2>/dev/null | head -1)
[ -n "$kofile" ] && ok "the module is at /$kofile" || nok "no hapticctrl.ko* under /lib/modules/$krel/updates/dkms"
vm=$(in_chroot modinfo -F vermagic "/$kofile" 2>/dev/null)
echo "# vermagic: $vm"
[[ "$vm" == "$krel SMP preempt_rt mod_unload"* ]] && ok "vermagic is the stock kernel's ($krel SMP preempt_rt)" || nok "vermagic '$vm'"
signer=$(in_chroot modinfo -F signer "/$kofile" 2>/dev/null)
echo "# signer: ${signer:-none}"
[ -n "$signer" ] && ok "dkms signed the module (signer: $signer)" || nok "the DKMS-built module is not signed"
# The tools installed from the package run in the chroot (trixie's libc).
check "hapctl --help runs" in_chroot hapctl --help
check "proto_interface --help runs" in_chroot proto_interface --help
check "hapdev --help runs" in_chroot hapdev --help
check "virtuose_demo --help runs" in_chroot virtuose_demo --help
# An application spelling the header and the library as Haption's do builds
# against the installed package and runs (no controller needed for the
# version).
printf '#include "virtuoseAPI.h"\n#include <stdio.h>\nint main(void) { int a = 0, b = 0; virtAPIVersion(&a, &b); printf("%%d.%%d\\n", a, b); return a != 4; }\n' >"$C/tmp/hap-debs/app.c"
for l in -lvirtuose -lVirtuoseAPI -lvirtuoseDLL -l:virtuoseAPI.so; do
  check "an application with #include \"virtuoseAPI.h\" and $l builds and runs against the package" \
    in_chroot sh -c "cc /tmp/hap-debs/app.c $l -o /tmp/hap-debs/app && /tmp/hap-debs/app"
done
check "a bad argument is a clear error, not a panic" sh -c "! bash '$DK' run proto_interface --no-such-option 2>&1 | grep -q panicked"
check "hapticctrl.sh status says the module is not loaded" sh -c "bash '$DK' run hapticctrl.sh status 2>&1 | grep -q 'module: not loaded'"

# The DKMS-built module on Debian's own kernel in QEMU.
case "$kofile" in
  *.xz) xz -dc "$C/$kofile" >"$work/hapticctrl.ko" ;;
  *.zst) zstd -qdc "$C/$kofile" >"$work/hapticctrl.ko" ;;
  *) cp "$C/$kofile" "$work/hapticctrl.ko" 2>/dev/null ;;
esac
if [ -s "$work/hapticctrl.ko" ]; then
  out=$(bash "$ROOT/scripts/qemu-run.sh" --stock --ko "$work/hapticctrl.ko" --icount --timeout 240 --log "$work/dkms-skeleton.log" "$ROOT/tests/qemu/01-skeleton.sh" 2>&1)
  rc=$?
  echo "$out" | grep -E '^HAPTEST-KERNEL|passed, [0-9]+ failed' | sed 's/^/# guest: /'
  [ "$rc" = 0 ] && ok "the DKMS-built module passes 01-skeleton on $krel in QEMU" || nok "01-skeleton with the DKMS-built module: $(echo "$out" | grep -E '^not ok|qemu-run' | head -5)"
else
  nok "no DKMS-built module to boot"
fi

# Signature enforcement: the stock kernel with module.sig_enforce=1.
if [ -f "$ROOT/build/stock/module/hapticctrl.ko" ]; then
  cp "$ROOT/build/stock/module/hapticctrl.ko" "$work/unsigned.ko"
  cp "$work/unsigned.ko" "$work/signed.ko"
  if in_chroot bash "$ROOT/scripts/sign-module.sh" --new-key --key-dir "$work/mok" >/dev/null 2>&1 &&
     in_chroot bash "$ROOT/scripts/sign-module.sh" --key-dir "$work/mok" --kdir "/usr/src/linux-headers-$krel" "$work/signed.ko" >/dev/null 2>&1; then
    ok "sign-module.sh made a key and signed the module with the kernel's sign-file"
  else
    nok "sign-module.sh"
  fi
  check "sign-module.sh refuses to overwrite the key" sh -c "! bash '$DK' run bash '$ROOT/scripts/sign-module.sh' --new-key --key-dir '$work/mok'"
  check "sign-module.sh refuses to sign twice" sh -c "! bash '$DK' run bash '$ROOT/scripts/sign-module.sh' --key-dir '$work/mok' --kdir /usr/src/linux-headers-$krel '$work/signed.ko'"
  out=$(HAP_APPEND="module.sig_enforce=1" bash "$ROOT/scripts/qemu-run.sh" --stock --ko "$work/unsigned.ko" --timeout 180 \
    --extra "$work/signed.ko:/lib/modules/hapticctrl-signed.ko" --log "$work/sig-enforce.log" "$ROOT/tests/guest/sig-enforce.sh" 2>&1)
  rc=$?
  echo "$out" | grep -E '^(ok|not ok) ' | sed 's/^/# guest: /'
  [ "$rc" = 0 ] && ok "module.sig_enforce=1 refuses the unsigned and the unenrolled-key modules" || nok "signature enforcement: $(echo "$out" | grep -E '^not ok|qemu-run' | head -5)"
else
  nok "no build/stock/module/hapticctrl.ko (make STOCK=1) for the signature test"
fi

# The host bench never runs on a kernel the module was not built for (this
# machine's), nor in CI; it refuses before installing or loading anything.
out=$(env -u CI bash "$ROOT/scripts/bench-rt.sh" --host --ko "$ROOT/build/stock/module/hapticctrl.ko" --cycles 10 2>&1); rc=$?
[ "$rc" = 3 ] && echo "$out" | grep -q "built for '$krel', the running kernel is '$(uname -r)'" && ! grep -q '^hapticctrl ' /proc/modules &&
  ok "bench-rt.sh --host refuses a module built for another kernel" || nok "bench-rt.sh --host (exit $rc): $out"
out=$(CI=true bash "$ROOT/scripts/bench-rt.sh" --host --cycles 10 2>&1); rc=$?
[ "$rc" = 3 ] && echo "$out" | grep -q 'CI=true' && ok "bench-rt.sh --host refuses under CI=true" || nok "bench-rt.sh --host under CI (exit $rc): $out"

# Purge: the module goes, the chroot is as before.
in_chroot apt-get purge -y -q hapticctrl-dkms hapticctrl-tools >"$work/apt-purge.log" 2>&1 && ok "apt purges both packages" || nok "apt purge: $(tail -5 "$work/apt-purge.log")"
left=$(cd "$C" && ls lib/modules/"$krel"/updates/dkms/hapticctrl.ko* 2>/dev/null)
[ -z "$left" ] && ok "purging removed the module" || nok "left behind: $left"
rm -rf "$C/tmp/hap-debs"
echo "debian: $pass passed, $fail failed"
[ "$fail" = 0 ]
