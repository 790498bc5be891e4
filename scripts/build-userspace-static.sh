#!/usr/bin/env bash
# Build the userspace binaries that run inside the QEMU guest as static
# executables (the guest is a busybox initramfs without a libc):
# proto_interface, hapctl (without the plotting feature) and hapdev.
# They land in userspace/target/x86_64-unknown-linux-gnu/release/.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
cd "$HAP_ROOT/userspace"
export RUSTFLAGS="-C target-feature=+crt-static"
log "building static guest binaries (proto_interface, hapctl, hapdev)"
cargo build --release --quiet --target x86_64-unknown-linux-gnu -p proto_interface -p hapdev
cargo build --release --quiet --target x86_64-unknown-linux-gnu -p hapctl --no-default-features
out=target/x86_64-unknown-linux-gnu/release
for b in proto_interface hapctl hapdev; do
  [ -x "$out/$b" ] || die "$out/$b was not built"
  if file "$out/$b" 2>/dev/null | grep -q 'dynamically linked'; then die "$b is not static"; fi
done
log "static guest binaries ready in userspace/$out"
