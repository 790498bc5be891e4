#!/usr/bin/env bash
# Self-test of scripts/check-ko-symbols.sh on objects compiled here with the
# kernel's relevant rustc flags (overflow checks on, panic=abort, v0 symbols):
# a crate named `hapticctrl` with known panic sites must fail the check with
# each site listed under its function and file; the same functions written
# with explicit arithmetic and get() must pass.
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

if build bad "$bad_fixed" && build good "$good_fixed"; then
  out=$(HAP_PANIC_SITES_MAX=0 bash "$HERE/scripts/check-ko-symbols.sh" "$tmp/bad.o" 2>&1); rc=$?
  [ "$rc" -ne 0 ] && ok "panic sites fail the check" || ko "panic sites passed the check: $out"
  for want in 'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::add: panic_const_add_overflow' \
              'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::pick: panic_bounds_check' \
              'userspace/hap-core/src/fixed.rs: hapticctrl::hap_core::fixed::first: core::option::unwrap_failed' \
              '3 userspace/hap-core/src/fixed.rs' \
              '3 panic call site(s)'; do
    case "$out" in *"$want"*) ok "listed: $want" ;; *) ko "not listed: $want in: $out" ;; esac
  done
  out=$(bash "$HERE/scripts/check-ko-symbols.sh" "$tmp/good.o" 2>&1); rc=$?
  [ "$rc" -eq 0 ] && ok "explicit arithmetic passes" || ko "clean object failed: $out"
  case "$out" in *"no panic call site"*) ok "clean object reported clean" ;; *) ko "no clean line: $out" ;; esac
else
  ko "could not compile the test objects"
fi
echo "check-ko-symbols self-test: $pass passed, $fail failed"
[ "$fail" -eq 0 ]
