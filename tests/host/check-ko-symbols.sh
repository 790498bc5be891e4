#!/usr/bin/env bash
# Self-test of scripts/check-ko-symbols.sh on objects compiled here with the
# kernel's relevant rustc flags (overflow checks on, panic=abort, v0 symbols):
# a crate named `hapticctrl` with known panic sites must fail the check with
# each site listed under its function and file, and so must one with a single
# site; the same functions written with explicit arithmetic and get() must
# pass. Each case runs with LLVM's tools and with binutils' (objdump, nm,
# c++filt: what the Debian chroot of `make STOCK=1` has), whichever are here.
set -uo pipefail
HERE=$(cd "$(dirname "$0")/../.." && pwd)
RUSTC=${RUSTC:-/usr/bin/rustc}
command -v "$RUSTC" >/dev/null || RUSTC=rustc
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok: $1"; }
ko() { fail=$((fail + 1)); echo "FAIL: $1"; }

build() { # NAME FIXED_RS: a crate laid out like the module (hap-core by #[path])
  mkdir -p "$tmp/$1/hap-core"
  printf '%s\n' '#![no_std]' '#[path = "hap-core/lib.rs"] pub mod hap_core;' > "$tmp/$1/hapticctrl.rs"
  printf '%s\n' 'pub mod fixed;' > "$tmp/$1/hap-core/lib.rs"
  printf '%s\n' "$2" > "$tmp/$1/hap-core/fixed.rs"
  "$RUSTC" --edition 2021 --crate-type lib --crate-name hapticctrl -Copt-level=2 \
    -Coverflow-checks=y -Cpanic=abort -Ccodegen-units=1 -Csymbol-mangling-version=v0 \
    --emit=obj="$tmp/$1.o" "$tmp/$1/hapticctrl.rs" 2>"$tmp/$1.err" || { cat "$tmp/$1.err"; return 1; }
}

bad_fixed='#[inline(never)] pub fn add(a: i64, b: i64) -> i64 { a + b }
#[inline(never)] pub fn pick(v: &[u8], i: usize) -> u8 { v[i] }
#[inline(never)] pub fn first(v: &[u8]) -> u8 { *v.first().unwrap() }'
good_fixed='#[inline(never)] pub fn add(a: i64, b: i64) -> i64 { a.saturating_add(b) }
#[inline(never)] pub fn pick(v: &[u8], i: usize) -> u8 { v.get(i).copied().unwrap_or(0) }
#[inline(never)] pub fn first(v: &[u8]) -> u8 { v.first().copied().unwrap_or(0) }'
# One site among clean functions: there is no tolerated number of sites.
one_fixed='#[inline(never)] pub fn add(a: i64, b: i64) -> i64 { a.saturating_add(b) }
#[inline(never)] pub fn pick(v: &[u8], i: usize) -> u8 { v.get(i).copied().unwrap_or(0) }
#[inline(never)] pub fn count(v: &[u8]) -> usize { v.iter().enumerate().filter(|(i, b)| **b as usize == *i).count() }'

# Tool sets: "LABEL NM OBJDUMP CXXFILT", those installed here.
toolsets=()
for set in "llvm llvm-nm-22 llvm-objdump-22 llvm-cxxfilt-22" "binutils nm objdump c++filt"; do
  read -r label nm od cf <<<"$set"
  if command -v "$nm" >/dev/null && command -v "$od" >/dev/null && command -v "$cf" >/dev/null; then
    toolsets+=("$set")
  else
    echo "skip: $label tools not installed"
  fi
done
[ "${#toolsets[@]}" -gt 0 ] || ko "neither LLVM's nor binutils' tools are installed"

check() { # TOOLSET OBJECT: run the check with that tool set
  local label nm od cf
  read -r label nm od cf <<<"$1"
  HAP_NM=$nm HAP_OBJDUMP=$od HAP_CXXFILT=$cf bash "$HERE/scripts/check-ko-symbols.sh" "$2" 2>&1
}

if build bad "$bad_fixed" && build good "$good_fixed" && build one "$one_fixed"; then
  for set in "${toolsets[@]}"; do
    t=${set%% *}
    out=$(check "$set" "$tmp/bad.o"); rc=$?
    [ "$rc" -ne 0 ] && ok "$t: panic sites fail the check" || ko "$t: panic sites passed the check: $out"
    for want in 'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::add: panic_const_add_overflow' \
                'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::pick: panic_bounds_check' \
                'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::first: core::option::unwrap_failed' \
                '3 userspace/hap-core/src/fixed.rs' \
                '3 panic call site(s)'; do
      case "$out" in *"$want"*) ok "$t: listed: $want" ;; *) ko "$t: not listed: $want in: $out" ;; esac
    done
    out=$(check "$set" "$tmp/one.o"); rc=$?
    [ "$rc" -ne 0 ] && ok "$t: a single panic site fails the check" || ko "$t: a single site passed: $out"
    case "$out" in *'hapticctrl::hap_core::fixed::count: panic_const_add_overflow'*'1 panic call site(s)'*)
      ok "$t: the single site is listed" ;; *) ko "$t: single site not listed: $out" ;; esac
    out=$(check "$set" "$tmp/good.o"); rc=$?
    [ "$rc" -eq 0 ] && ok "$t: explicit arithmetic passes" || ko "$t: clean object failed: $out"
    case "$out" in *"no panic call site"*) ok "$t: clean object reported clean" ;; *) ko "$t: no clean line: $out" ;; esac
  done
  # A demangler that does not know Rust's v0 symbols would see no site at all:
  # the check refuses it rather than pass.
  out=$(HAP_CXXFILT=cat bash "$HERE/scripts/check-ko-symbols.sh" "$tmp/bad.o" 2>&1); rc=$?
  case "$rc:$out" in 0:*) ko "a non-demangler passed the check: $out" ;;
    *"does not demangle Rust v0"*) ok "a non-demangler is refused" ;; *) ko "no refusal line: $out" ;; esac
else
  ko "could not compile the test objects"
fi
echo "check-ko-symbols self-test: $pass passed, $fail failed"
[ "$fail" -eq 0 ]
