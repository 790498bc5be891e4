#!/usr/bin/env bash
# Build the guest's initramfs: busybox, /init, the hapticctrl module, our
# static userspace binaries (if built), the in-guest test library and the
# given test script (run by /init as /test.sh).
#   scripts/mkinitramfs.sh OUT.cpio.gz KO TEST_SCRIPT [FILE:GUEST_PATH ...]
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"

out=${1:?usage: mkinitramfs.sh OUT.cpio.gz KO TEST_SCRIPT [FILE:GUEST_PATH ...]}
ko=${2:?module path}
test_script=${3:?test script}
shift 3
[ -f "$ko" ] || die "module $ko not found (run make)"
[ -f "$test_script" ] || die "test script $test_script not found"

root=$(mktemp -d)
trap 'rm -rf "$root"' EXIT
# mktemp makes the directory 0700: as the archive's "." it would become the
# guest's "/", which no unprivileged process (the bridge after its drop)
# could traverse to reach /dev, /run or /etc.
chmod 0755 "$root"
mkdir -p "$root"/{bin,sbin,dev,proc,sys,tmp,run,etc,lib/modules,usr/bin,usr/sbin,tests,data}
cp /bin/busybox "$root/bin/busybox"
for applet in $("$root/bin/busybox" --list); do
  [ -e "$root/bin/$applet" ] || ln -s busybox "$root/bin/$applet"
done
cp "$ko" "$root/lib/modules/hapticctrl.ko"
cp "$test_script" "$root/test.sh"
chmod +x "$root/test.sh"
cp "$HAP_ROOT/tests/qemu/lib.sh" "$root/tests/lib.sh"
[ -f "$HAP_ROOT/scripts/hapticctrl.sh" ] && cp "$HAP_ROOT/scripts/hapticctrl.sh" "$root/usr/sbin/hapticctrl.sh"
# Static userspace binaries, when built (scripts/build-userspace-static.sh).
static_dir="$HAP_ROOT/userspace/target/x86_64-unknown-linux-gnu/release"
for b in proto_interface hapctl hapdev; do
  [ -x "$static_dir/$b" ] && cp "$static_dir/$b" "$root/usr/bin/$b"
done
for extra in "$@"; do
  src=${extra%%:*}; dst=${extra#*:}
  mkdir -p "$root/$(dirname "$dst")"; cp "$src" "$root/$dst"
done
# The bridge's unprivileged user (hapticctrl.sh runs proto_interface as it).
printf 'root:x:0:0:root:/:/bin/sh\nhapticctrl:x:990:990:hapticctrl bridge:/nonexistent:/bin/false\n' >"$root/etc/passwd"
printf 'root:x:0:\nhapticctrl:x:990:\n' >"$root/etc/group"

cat >"$root/init" <<'INIT'
#!/bin/sh
# hapticctrl guest init: mount, network, run /test.sh, report, power off.
export PATH=/bin:/sbin:/usr/bin:/usr/sbin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev 2>/dev/null
mount -t tmpfs tmp /tmp
mount -t tmpfs run /run
# Drivers a distribution kernel builds as modules (virtio-net for Debian's),
# in dependency order (scripts/qemu-run.sh --stock puts them here).
for m in /lib/modules/boot/*.ko; do
  [ -f "$m" ] && insmod "$m"
done
for _ in 1 2 3 4 5 6 7 8 9 10; do
  [ -d /lib/modules/boot ] && [ ! -e /sys/class/net/eth0 ] || break
  sleep 0.1
done
if [ -e /sys/class/net/eth0 ]; then
  ip link set lo up
  ip link set eth0 up
  ip addr add 10.0.2.15/24 dev eth0
  ip route add default via 10.0.2.2
fi
echo "HAPTEST-BEGIN $(uname -r) $(cat /proc/cmdline)"
echo "HAPTEST-KERNEL $(uname -rv)"
cmdline=$(cat /proc/cmdline)
args=""
for w in $cmdline; do case "$w" in hap.args=*) args=$(echo "${w#hap.args=}" | tr ',' ' ') ;; esac; done
sh /test.sh $args
rc=$?
echo "HAPTEST-RESULT rc=$rc"
dmesg > /tmp/dmesg.txt
poweroff -f
INIT
chmod +x "$root/init"

# /dev/console must exist before devtmpfs is mounted by /init.
(cd "$root" && { find . -print0 | cpio --null -o -H newc --quiet; } ) >"$out.tmp.cpio"
# mknod-free /dev/console: append a cpio entry made by gen_init_cpio-style list.
python3 - "$out.tmp.cpio" <<'PY'
import sys, os
path = sys.argv[1]
data = open(path, "rb").read()
# Drop the trailer, add /dev/console (char 5:1), re-add the trailer.
trailer = data.rfind(b"070701")
body = data[:trailer]
def entry(name, mode, rmaj=0, rmin=0, ino=900001):
    name_b = name.encode() + b"\0"
    hdr = "070701" + "".join("%08X" % v for v in [ino, mode, 0, 0, 1, 0, 0, 0, 0, rmaj, rmin, len(name_b), 0])
    out = hdr.encode() + name_b
    out += b"\0" * ((4 - len(out) % 4) % 4)
    return out
body += entry("dev/console", 0o020600, 5, 1)
body += entry("TRAILER!!!", 0, ino=0)
body += b"\0" * ((512 - len(body) % 512) % 512)
open(path, "wb").write(body)
PY
gzip -1 -c "$out.tmp.cpio" >"$out"
rm -f "$out.tmp.cpio"
