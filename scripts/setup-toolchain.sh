#!/usr/bin/env bash
# Install everything hapticctrl needs to build its test kernel, its Rust kernel
# module and its userspace, on a Debian 12 (bookworm) machine. Idempotent: a
# second run checks a stamp and the tools' versions and returns in a second.
#
# Facts behind the choices: Documentation/development.md ("Toolchain").
#  - rustc-web + rust-web-src (bookworm-security) are a matching pair: the
#    kernel builds `core` from that source with that compiler.
#  - clang/lld/llvm 22 share rustc-web's LLVM; bindgen needs libclang >= 17.
#  - linux-source-7.3 comes from trixie-backports, QEMU 10 from
#    bookworm-backports. Suites beyond bookworm get Pin-Priority 100 so that
#    only the packages named here come from them; nothing installed is upgraded.
#
#   scripts/setup-toolchain.sh            the build and test toolchain
#   scripts/setup-toolchain.sh --bench    only the benchmark tools (rt-tests:
#                                         cyclictest + hackbench, stress-ng,
#                                         valgrind); the bench-*.sh scripts
#                                         call it; CI does not need them
set -euo pipefail

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
# shellcheck source=scripts/lib.sh
. "$HERE/lib.sh"

BINDGEN_VERSION=0.73.2
STAMP_VERSION=4 # bump when the package list below changes

APT_PACKAGES_BOOKWORM=(
  build-essential flex bison bc cpio kmod libelf-dev busybox-static
  python3 rsync xz-utils zstd file
)
# Optional: the demo's browser test (it says SKIPPED without it).
APT_PACKAGES_OPTIONAL=(chromium)
APT_PACKAGES_SECURITY=(
  rustc-web rust-web-src clang-22 lld-22 llvm-22 libclang-22-dev
)
APT_PACKAGES_BPO=(qemu-system-x86 qemu-system-common qemu-system-data seabios)
APT_PACKAGES_TRIXIE_BPO=(linux-source-7.3)

SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO=sudo; fi

stamp="$HAP_CACHE/toolchain.stamp"

# Benchmark tools, from bookworm itself; same dry-run guard as below.
APT_PACKAGES_BENCH=(rt-tests stress-ng valgrind)
if [ "${1:-}" = --bench ]; then
  missing=()
  for p in "${APT_PACKAGES_BENCH[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    log "benchmark tools already installed (${APT_PACKAGES_BENCH[*]})"
    exit 0
  fi
  log "apt: ${missing[*]} (benchmark tools)"
  plan=$($SUDO apt-get -s -y --no-install-recommends install "${missing[@]}" 2>&1) ||
    { $SUDO apt-get update -q -o Acquire::Retries=3 >/dev/null; plan=$($SUDO apt-get -s -y --no-install-recommends install "${missing[@]}"); }
  if echo "$plan" | grep -E '^(Remv|Inst [^ ]+ \[)' >/dev/null; then
    echo "$plan" | grep -E '^(Remv|Inst [^ ]+ \[)' >&2
    die "apt would upgrade or remove installed packages (above); refusing"
  fi
  $SUDO apt-get install -y -q --no-install-recommends -o Acquire::Retries=3 "${missing[@]}" >/dev/null
  exit 0
elif [ $# -gt 0 ]; then
  die "unknown argument $1 (usage: setup-toolchain.sh [--bench])"
fi

toolchain_ok() {
  [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$STAMP_VERSION" ] || return 1
  [ -x /usr/bin/rustc ] && /usr/bin/rustc --version | grep -q '^rustc 1\.9[6-9]' || return 1
  [ -d /usr/lib/rustlib/src/rust/library/core ] || return 1
  command -v clang-22 >/dev/null && command -v ld.lld-22 >/dev/null || return 1
  [ -x "$HAP_TOOLS/bin/bindgen" ] && "$HAP_TOOLS/bin/bindgen" --version | grep -q " $BINDGEN_VERSION\$" || return 1
  command -v qemu-system-x86_64 >/dev/null && [ -x /bin/busybox ] || return 1
  command -v chromium >/dev/null || [ -f "$HAP_CACHE/chromium.skipped" ] || return 1
  ls /usr/src/linux-source-7.3.tar.* >/dev/null 2>&1 || return 1
  return 0
}

if toolchain_ok; then
  log "toolchain already installed ($(/usr/bin/rustc --version), clang-22, bindgen $BINDGEN_VERSION, $(qemu-system-x86_64 --version | head -1)): nothing to do"
  exit 0
fi

log "installing the hapticctrl toolchain (this takes a minute or two)"
mkdir -p "$HAP_CACHE" "$HAP_TOOLS"

# Extra suites, all at low priority.
$SUDO tee /etc/apt/sources.list.d/hapticctrl-suites.sources >/dev/null <<'EOF'
# Added by hapticctrl scripts/setup-toolchain.sh. Only packages named there
# come from these suites (see /etc/apt/preferences.d/hapticctrl).
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm-backports trixie trixie-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
$SUDO tee /etc/apt/preferences.d/hapticctrl >/dev/null <<'EOF'
# Added by hapticctrl scripts/setup-toolchain.sh: never prefer the newer suites.
Package: *
Pin: release n=trixie
Pin-Priority: 100

Package: *
Pin: release n=trixie-backports
Pin-Priority: 100

Package: *
Pin: release n=bookworm-backports
Pin-Priority: 100
EOF

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q -o Acquire::Retries=3 >/dev/null

# Leave installed packages alone: only ask for what is missing.
missing=()
for p in "${APT_PACKAGES_BOOKWORM[@]}" "${APT_PACKAGES_SECURITY[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
for p in "${APT_PACKAGES_BPO[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p/bookworm-backports")
done
for p in "${APT_PACKAGES_TRIXIE_BPO[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p/trixie-backports")
done

if [ ${#missing[@]} -gt 0 ]; then
  log "apt: ${missing[*]}"
  # Dry run first: refuse to go on if apt wants to upgrade or remove anything.
  plan=$($SUDO apt-get -s -y --no-install-recommends install "${missing[@]}")
  if echo "$plan" | grep -E '^(Remv|Inst [^ ]+ \[)' >/dev/null; then
    echo "$plan" | grep -E '^(Remv|Inst [^ ]+ \[)' >&2
    die "apt would upgrade or remove installed packages (above); refusing"
  fi
  $SUDO apt-get install -y -q --no-install-recommends -o Acquire::Retries=3 "${missing[@]}" >/dev/null
fi

for p in "${APT_PACKAGES_OPTIONAL[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' && continue
  plan=$($SUDO apt-get -s -y --no-install-recommends install "$p" 2>&1 || true)
  if echo "$plan" | grep -qE '^(Remv|Inst [^ ]+ \[)' || ! echo "$plan" | grep -q "^Inst $p "; then
    log "warning: not installing optional $p (apt would change installed packages or cannot find it)"
    touch "$HAP_CACHE/chromium.skipped"
  else
    log "apt: $p (optional, for the browser test)"
    $SUDO apt-get install -y -q --no-install-recommends -o Acquire::Retries=3 "$p" >/dev/null || touch "$HAP_CACHE/chromium.skipped"
  fi
done

# bindgen-cli at a pinned version, built with the machine's cargo into our tool dir.
if ! { [ -x "$HAP_TOOLS/bin/bindgen" ] && "$HAP_TOOLS/bin/bindgen" --version | grep -q " $BINDGEN_VERSION\$"; }; then
  log "cargo install bindgen-cli $BINDGEN_VERSION (about a minute)"
  cargo install --quiet --locked --root "$HAP_TOOLS" bindgen-cli --version "$BINDGEN_VERSION"
fi

toolchain_ok || { echo "$STAMP_VERSION" >"$stamp"; toolchain_ok; } || die "toolchain check failed after install"
echo "$STAMP_VERSION" >"$stamp"
log "toolchain ready: $(/usr/bin/rustc --version); $(clang-22 --version | head -1); bindgen $BINDGEN_VERSION; $(qemu-system-x86_64 --version | head -1)"
