# Shared by the host<->guest e2e scripts: TAP-style counting of checks.
# Source it after ROOT is set; it defines pass, fail and the check helpers.
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
isnum() { [[ "$1" =~ ^-?[0-9]+(\.[0-9]+)?$ ]]; }
check_num() { # desc value op limit (a missing value fails)
  if isnum "$2" && isnum "$4" && awk -v v="$2" -v l="$4" "BEGIN { exit !(v $3 l) }"; then ok "$1 ($2 $3 $4)"; else nok "$1 (got '$2', want $3 $4)"; fi
}
# sum N... : the integers' sum, or nothing if one is missing (a check on it
# then fails instead of the script stopping on bad arithmetic).
sum() {
  local s=0 v
  for v in "$@"; do [[ "$v" =~ ^-?[0-9]+$ ]] || return 0; s=$((s + v)); done
  echo "$s"
}
