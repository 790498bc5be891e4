# Common settings for hapticctrl's scripts. Sourced, not run.
# shellcheck shell=bash

HAP_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
# Everything built outside the checkout (kernel trees, tools) lives here, so a
# fresh clone on the same machine reuses it.
HAP_CACHE=${HAP_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/hapticctrl}
HAP_TOOLS="$HAP_CACHE/tools"
HAP_KERNEL_VERSION=7.3
# LLVM suffix: Debian names the tools clang-22, ld.lld-22, ...
HAP_LLVM=-22
HAP_RUSTC=/usr/bin/rustc
export PATH="$HAP_TOOLS/bin:$PATH"

# What counts as a kernel problem in a guest log (grep -E): panics, oopses,
# warnings, lockdep and atomic-sleep splats, sanitizers, Rust panics. Each
# pattern holds a space or a colon, so that the base64 of a guest log dump
# (the simulator log) never matches one.
HAP_SPLAT_RE='Kernel panic|Oops: |WARNING:|BUG:|Call Trace|possible (circular|recursive) locking|sleeping function called from invalid context|general protection fault|KASAN: |UBSAN: |rust_panic|panicked at'

# hap_usage: print the calling script's header comment (its --help).
hap_usage() { awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; }
# hap_uint OPTION VALUE: die unless VALUE is a non-negative integer.
hap_uint() { [[ "$2" =~ ^[0-9]+$ ]] || die "$1 needs a non-negative integer, got '$2' (see --help)"; }

# hap_keyfile FILE: make sure FILE holds a pre-shared key for the bridge and
# its test client (64 hex digits, mode 0600; what `hapctl keygen` writes),
# creating it if missing; prints FILE.
hap_keyfile() {
  if [ ! -f "$1" ]; then
    mkdir -p "$(dirname "$1")"
    (umask 077 && python3 -c 'import secrets; print(secrets.token_hex(32))' > "$1") || die "cannot write the key $1"
  fi
  chmod 600 "$1"
  echo "$1"
}

log() { printf '[hapticctrl %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
die() { printf '[hapticctrl] error: %s\n' "$*" >&2; exit 1; }

# The config fragments of a variant ("" = base, "debug", "kasan" = debug +
# KASAN), one path per line, in merge order.
hap_kernel_frags() {
  local variant=${1:-}
  echo "$HAP_ROOT/scripts/kernel.config"
  case "$variant" in
    debug) echo "$HAP_ROOT/scripts/kernel-debug.config" ;;
    kasan) echo "$HAP_ROOT/scripts/kernel-debug.config"; echo "$HAP_ROOT/scripts/kernel-kasan.config" ;;
  esac
}

# The kernel build directory for a variant ("", "debug" or "kasan"): keyed by
# the kernel source package version and the hash of the config fragments.
hap_kernel_dir() {
  local variant=${1:-}
  local frags
  mapfile -t frags < <(hap_kernel_frags "$variant")
  local srcver
  srcver=$(dpkg-query -W -f='${Version}' "linux-source-$HAP_KERNEL_VERSION" 2>/dev/null || echo unknown)
  local hash
  hash=$(cat "${frags[@]}" | sha256sum | cut -c1-12)
  echo "$HAP_CACHE/kernel/${srcver//[^A-Za-z0-9.+-]/_}-${variant:-base}-$hash"
}

# hap_add_binaries BIN...: append to the array HAP_EXTRAS the qemu-run.sh
# "--extra SRC:DST" arguments that put each host binary (found in PATH) at
# /usr/bin/NAME in the guest, with the dynamic libraries and loader ldd lists
# at their own paths (Debian's rt-tests and stress-ng are dynamic). Missing
# binaries are skipped with a message; returns 1 if any was missing.
hap_add_binaries() {
  local b bin lib rc=0
  declare -gA HAP_EXTRAS_SEEN
  declare -ga HAP_EXTRAS
  for b in "$@"; do
    if ! bin=$(command -v "$b"); then
      log "$b not found in PATH: not added to the guest"
      rc=1
      continue
    fi
    HAP_EXTRAS+=(--extra "$bin:/usr/bin/$(basename "$bin")")
    while read -r lib; do
      [ -n "${HAP_EXTRAS_SEEN[$lib]:-}" ] && continue
      HAP_EXTRAS_SEEN[$lib]=1
      HAP_EXTRAS+=(--extra "$lib:$lib")
    done < <(ldd "$bin" | sed -n -e 's/.*=> \(\/[^ ]*\) .*/\1/p' -e 's/^[[:space:]]*\(\/[^ ]*\) .*/\1/p')
  done
  return $rc
}

# hap_kmod_order MODULES.DEP NAME...: the paths (relative to the modules
# directory, as in modules.dep) of the named modules and all they depend on,
# each once, dependencies first: the order in which to insmod them.
hap_kmod_order() {
  python3 - "$@" <<'PY'
import os, sys
dep_file, names = sys.argv[1], sys.argv[2:]
deps, by_name = {}, {}
for line in open(dep_file):
    mod, _, rest = line.partition(":")
    deps[mod] = rest.split()
    base = os.path.basename(mod).split(".ko")[0]
    by_name[base] = by_name[base.replace("-", "_")] = mod
order, seen = [], set()
def visit(m):
    if m in seen:
        return
    seen.add(m)
    for d in deps.get(m, []):
        visit(d)
    order.append(m)
for n in names:
    if n not in by_name:
        sys.exit("hap_kmod_order: no module %s in %s" % (n, dep_file))
    visit(by_name[n])
print("\n".join(order))
PY
}
