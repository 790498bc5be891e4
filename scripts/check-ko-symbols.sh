#!/usr/bin/env bash
# Fail if a module references soft-float or 128-bit integer helpers: the
# kernel's versions of those panic (decision 1 in DEVELOPERS.md).
set -euo pipefail
ko=${1:?usage: check-ko-symbols.sh MODULE.ko}
[ -f "$ko" ] || { echo "check-ko-symbols: $ko not found" >&2; exit 1; }
NM=$(command -v llvm-nm-22 || command -v nm)
bad=$("$NM" -u "$ko" | awk '{print $NF}' | grep -E '^__(add|sub|mul|div|neg|eq|ne|lt|le|gt|ge|unord|extend|trunc|fix|fixuns|float|floatun|pow|cmp)[a-z]*(sf|df|tf|xf)[0-9]*$|ti3$|oti4$|^__(u)?(div|mod|mul)ti|^f(loor|ceil|sqrt|abs)f?$' || true)
if [ -n "$bad" ]; then
  echo "check-ko-symbols: $ko references helpers that panic in the kernel:" >&2
  echo "$bad" | sed 's/^/  /' >&2
  exit 1
fi
echo "check-ko-symbols: $ko: no soft-float or 128-bit helper references ($("$NM" -u "$ko" | wc -l) undefined symbols checked)"
