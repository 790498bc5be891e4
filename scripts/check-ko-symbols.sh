#!/usr/bin/env bash
# Check the built module for code that can panic in the kernel:
#  1. references to soft-float or 128-bit integer helpers (the kernel's
#     versions of those panic);
#  2. panic call sites in the module's own functions (hap-core included, it is
#     compiled into the module): every relocation to a panic entry point of
#     `core` (core::panicking::*: panic, panic_fmt, panic_bounds_check,
#     panic_const_*_overflow, assert_failed ...; and the cold helpers that
#     call it: unwrap_failed, expect_failed, slice index and length failures)
#     in a function of the `hapticctrl` crate, or in a kernel-crate generic
#     instantiated for one of its types (module code inlined into the kernel's
#     glue). A Rust panic in CLOCK or SERVO is a kernel BUG().
# Both fail the check: one site is enough. Sites are listed per source file
# and function; panic sites in kernel-crate code (not ours) are only counted.
# Documentation/development.md says how to read the output.
set -euo pipefail
ko=${1:?usage: check-ko-symbols.sh MODULE.ko}
[ -f "$ko" ] || { echo "check-ko-symbols: $ko not found" >&2; exit 1; }
pick() { for t in "$@"; do command -v "$t" && return; done; return 1; }
# LLVM's tools when present (the project's kernels), else binutils' (the
# Debian chroot of `make STOCK=1`); HAP_NM, HAP_OBJDUMP, HAP_CXXFILT choose.
NM=${HAP_NM:-$(pick llvm-nm-22 nm)} || { echo "check-ko-symbols: no nm" >&2; exit 1; }
OBJDUMP=${HAP_OBJDUMP:-$(pick llvm-objdump-22 objdump)} || { echo "check-ko-symbols: no objdump" >&2; exit 1; }
DEMANGLE=${HAP_CXXFILT:-$(pick llvm-cxxfilt-22 llvm-cxxfilt c++filt)} || { echo "check-ko-symbols: no demangler (llvm-cxxfilt or c++filt)" >&2; exit 1; }
# GNU c++filt keeps the crate hashes (core[1b6169c1cdb4b588]::panicking::...),
# llvm-cxxfilt drops them: strip them, so that both read alike.
demangle() { "$DEMANGLE" | sed -E 's/\[[0-9a-f]{1,16}\]::/::/g'; }
probe=$(echo _RNvNtNtCs2lKf6AS60Zg_4core9panicking11panic_const24panic_const_add_overflow | demangle)
[ "$probe" = core::panicking::panic_const::panic_const_add_overflow ] ||
  { echo "check-ko-symbols: $DEMANGLE does not demangle Rust v0 symbols (got: $probe)" >&2; exit 1; }
status=0

bad=$("$NM" -u "$ko" | awk '{print $NF}' | grep -E '^__(add|sub|mul|div|neg|eq|ne|lt|le|gt|ge|unord|extend|trunc|fix|fixuns|float|floatun|pow|cmp)[a-z]*(sf|df|tf|xf)[0-9]*$|ti3$|oti4$|^__(u)?(div|mod|mul)ti|^f(loor|ceil|sqrt|abs)f?$' || true)
if [ -n "$bad" ]; then
  echo "check-ko-symbols: $ko references helpers that panic in the kernel:" >&2
  echo "$bad" | sed 's/^/  /' >&2
  status=1
else
  echo "check-ko-symbols: $ko: no soft-float or 128-bit helper references ($("$NM" -u "$ko" | wc -l) undefined symbols checked)"
fi

# Every call from a function to a `core` symbol: "<function> <target>"
# (mangled, v0); the panic paths among the targets are picked after demangling.
calls=$("$OBJDUMP" -dr "$ko" | awk '
  /^[0-9a-f]+ <.*>:$/ { fn = $2; gsub(/[<>:]/, "", fn) }
  /R_X86_64_[A-Z0-9]+[ \t]/ && /_4core/ { s = $NF; sub(/[-+]0x[0-9a-f]+$/, "", s); print fn, s }')
report=$(printf '%s\n' "$calls" | { grep . || true; } | while read -r fn sym; do
  printf '%s\t%s\t%s\n' "$fn" "$(printf '%s\n' "$fn" | demangle)" "$(printf '%s\n' "$sym" | demangle)"
done | perl -F'\t' -lane '
  my ($m, $fn, $sym) = @F;
  # The panic entry points of core: core::panicking::*, and the cold
  # helpers that call them (unwrap_failed, expect_failed, slice and str
  # index failures, copy_from_slice length mismatch, RefCell borrow ...).
  next unless $sym =~ /^core::panicking::/
    || $sym =~ /^(?:core::|_R\w*_4core).*(?:unwrap_failed|expect_failed|_fail\b|do_panic|panic_\w+)/;
  $sym =~ s/^core::panicking::(panic_const::)?//;
  # The first crate in a v0 symbol is the crate that defines the function.
  my $crate = "";
  if ($m =~ /Cs[A-Za-z0-9]+_(\d+)([A-Za-z_]\w*)/) { $crate = substr($2, 0, $1) }
  my $ours = $fn =~ /\bhapticctrl::/;   # a type of ours among the generic arguments
  my $class;
  if ($crate eq "hapticctrl") { $class = "own" }
  elsif ($crate eq "core" && $fn =~ /^core::panicking::/) { next }  # the panic machinery itself
  elsif ($ours && $fn =~ /^<kernel::miscdevice::MiscdeviceVTable</ && $sym =~ /^assert_failed/) {
    # rust/kernel/iov.rs: assert_eq! on the iterator direction, in the kernel
    # crate code that wraps every read_iter/write_iter.
    $class = "kernel";
  }
  elsif ($ours) { $class = "inlined" }
  else { $class = "kernel" }
  # Source file of the function: hap-core module -> its file, module file -> module/.
  my $file = "module/hapticctrl.rs";
  if ($fn =~ /hapticctrl::hap_core::(\w+)/) { $file = "userspace/hap-core/src/$1.rs" }
  elsif ($fn =~ /hapticctrl::(\w+)::/ && $1 ne "hap_core") { $file = "module/$1.rs" }
  print join("\t", $class, $file, $fn, $sym);')

own=$(printf '%s\n' "$report" | grep -cE '^(own|inlined)	' || true)
kern=$(printf '%s\n' "$report" | grep -cE '^kernel	' || true)
if [ "$own" -gt 0 ]; then
  echo "check-ko-symbols: $ko: $own panic call site(s) in the module's own code (file: function: panic symbol [count]):" >&2
  printf '%s\n' "$report" | grep -E '^(own|inlined)	' | sort | uniq -c |
    awk -F'\t' '{ split($1, a, " "); n = a[1]; cls = a[2];
      printf "  %s: %s: %s%s%s\n", $2, $3, $4, (n > 1 ? " [" n "]" : ""),
        (cls == "inlined" ? " (module code inlined into kernel glue)" : "") }' >&2
  echo "  per file:" >&2
  printf '%s\n' "$report" | grep -E '^(own|inlined)	' | cut -f2 | sort | uniq -c | sort -rn |
    awk '{ printf "    %3d %s\n", $1, $2 }' >&2
  echo "check-ko-symbols: FAIL: $own panic call site(s) in the module's own code" >&2
  status=1
else
  echo "check-ko-symbols: $ko: no panic call site in the module's own functions ($kern in kernel-crate code)"
fi
exit $status
