#!/usr/bin/env bash
# The newcomer's path, as the README gives it: scripts/install-virtuose-api.sh
# with its defaults (prefix /usr/local, ldconfig), then programs built with
# nothing but the compiler's default paths and started with no
# LD_LIBRARY_PATH, against the fake controller:
#  - tests/vapi/first.c: `cc first.c -lvirtuose`, with "virtuoseAPI.h" and
#    with <virtuose/virtuoseAPI.h>;
#  - first.c as C++ with the flags CHAI3D 3.2's makefiles derive from
#    VIRTUOSE_DIR=/usr/local (-I$VIRTUOSE_DIR/include,
#    -L$VIRTUOSE_DIR/lib/lin-x86_64 -l:virtuoseAPI.so);
#  - tests/vapi/apps.c built with the test header of Haption's 3.x form
#    (tests/vapi/haption3/virtuoseAPI.h, every virt* a wrapper calling
#    virtCallDLL) and -lvirtuose;
#  - pkg-config and CMake's find_package(VirtuoseAPI) with no search path
#    given;
#  - the install run a second time lists the same files.
#   tests/vapi/default-install.sh namespace|host RESULTS FAKE MS
# namespace: run by tests/vapi/run.sh under `unshare -m` (a private mount
# namespace): /usr/local and /etc are overlays on a tmpfs of that namespace,
# so the install and ldconfig's cache change nothing outside it. host: the
# real /usr/local and ld.so.cache (run.sh uses it as root when no mount
# namespace can be made; the install stays, and a second run replaces the
# same files). Prints "ok - ..." / "not ok - ..." per check.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
mode=${1:?namespace|host}; results=${2:?results dir}; fc=${3:?fake controller}; ms=${4:-300}
ok() { echo "ok - default install: $*"; }
nok() { echo "not ok - default install: $*"; }
mkdir -p "$results"

if [ "$mode" = namespace ]; then
  scratch=$(mktemp -d)
  mount -t tmpfs hap-vapi "$scratch" || { nok "tmpfs in the mount namespace"; exit 0; }
  for d in /usr/local /etc; do
    mkdir -p "$scratch$d/upper" "$scratch$d/work"
    if ! mount -t overlay hap-vapi -o "lowerdir=$d,upperdir=$scratch$d/upper,workdir=$scratch$d/work" "$d"; then
      nok "an overlay on $d in the mount namespace"; exit 0
    fi
  done
  echo "# in a private mount namespace: /usr/local and /etc are overlays on a tmpfs"
else
  echo "# on the host: installs into /usr/local and runs ldconfig (kept after the test)"
fi

# What a newcomer's shell has: no search paths of ours.
unset LD_LIBRARY_PATH LIBRARY_PATH CPATH C_INCLUDE_PATH CPLUS_INCLUDE_PATH PKG_CONFIG_PATH CMAKE_PREFIX_PATH

if bash "$ROOT/scripts/install-virtuose-api.sh" > "$results/install.txt" 2> "$results/install.err"; then
  ok "scripts/install-virtuose-api.sh with no argument installed $(wc -l < "$results/install.txt") files under /usr/local"
else
  sed 's/^/# /' "$results/install.err" | tail -5; nok "scripts/install-virtuose-api.sh"; exit 0
fi
grep -q '^ldconfig: the loader finds libvirtuose.so.4 in /usr/local/lib' "$results/install.err" \
  && ok "the install ran ldconfig and says so" || nok "the install did not report ldconfig: $(tail -2 "$results/install.err")"
cached=$(ldconfig -p | awk '$1 == "libvirtuose.so.4" && !f { f = $NF } END { print f }')
[ "$cached" = /usr/local/lib/libvirtuose.so.4 ] && ok "the loader's cache holds libvirtuose.so.4 => $cached" \
  || nok "the loader's cache: libvirtuose.so.4 => '${cached:-nothing}'"
for f in /usr/local/include/virtuose/virtuoseAPI.h /usr/local/lib/lin-x86_64/virtuoseAPI.so; do
  [ -e "$f" ] && ok "installed $f" || nok "not installed: $f"
done

# The fake controller (buttons released), one run per program.
start_fake() { # DIR
  mkfifo "$1/fake.in"
  "$fc" --duration 60 --center 0.45,0.05,0.25 --amplitude 0.01,0,0 --power-lag 200 --buttons 0 \
    < "$1/fake.in" > "$1/fake.txt" 2> "$1/fake.err" &
  fake_pid=$!
  exec {fake_hold}> "$1/fake.in"
  for _ in $(seq 100); do grep -q '^PORT ' "$1/fake.txt" && break; sleep 0.1; done
  port=$(sed -n 's/^PORT //p' "$1/fake.txt")
}
stop_fake() { exec {fake_hold}>&-; wait "$fake_pid"; }

# NAME: build in an empty directory with COMMAND..., run ./a.out ARGS with
# no LD_LIBRARY_PATH, expect exit 0.
try() { # NAME RUNARGS COMMAND...
  local name=$1 runargs=$2; shift 2
  local dir="$results/$name"
  mkdir -p "$dir"
  if ! (cd "$dir" && "$@") > "$dir/build.log" 2>&1; then
    sed 's/^/# /' "$dir/build.log" | head -10; nok "$name: $*"; return
  fi
  local needed
  needed=$(readelf -d "$dir/a.out" | sed -n 's/.*(NEEDED).*\[\(.*[Vv]irtuose.*\)\]/\1/p' | paste -sd,)
  start_fake "$dir"
  if [[ "$port" =~ ^[0-9]+$ ]]; then
    # shellcheck disable=SC2086
    (cd "$dir" && timeout 60 ./a.out "127.0.0.1#$port" $runargs) > "$dir/run.txt" 2>&1
    local rc=$?
    stop_fake
    if [ "$rc" = 0 ]; then
      ok "$name: '$*' builds and runs (needs $needed): $(grep -E '^(handle at|apps:)' "$dir/run.txt" | tail -1)"
    else
      grep -E '^not ok|virtOpen|error' "$dir/run.txt" | sed 's/^/# /' | head -8
      nok "$name: '$*' built, the program exited $rc"
    fi
  else
    stop_fake; nok "$name: the fake controller did not start: $(cat "$dir/fake.err")"
  fi
}
first=$ROOT/tests/vapi/first.c
apps=$ROOT/tests/vapi/apps.c
try first "" cc "$first" -lvirtuose
try first-subdir "" cc -DVIRTUOSE_SUBDIR "$first" -lvirtuose
VIRTUOSE_DIR=/usr/local
try chai3d-layout "" c++ -x c++ "$first" -x none -I"$VIRTUOSE_DIR/include" -L"$VIRTUOSE_DIR/lib/lin-x86_64" -l:virtuoseAPI.so
try haption3-header "$ms 0 0" cc -D_POSIX_C_SOURCE=200809L -I "$ROOT/tests/vapi/haption3" "$apps" -lvirtuose -lm
if command -v pkg-config > /dev/null; then
  # shellcheck disable=SC2046
  try pkg-config "" sh -c "cc '$first' \$(pkg-config --cflags --libs virtuose)"
fi
if command -v cmake > /dev/null; then
  mkdir -p "$results/cmake-src"
  cat > "$results/cmake-src/CMakeLists.txt" <<EOF
cmake_minimum_required(VERSION 3.13)
project(first C)
find_package(VirtuoseAPI REQUIRED)
add_executable(first "$first")
target_link_libraries(first VirtuoseAPI::VirtuoseAPI)
EOF
  try cmake "" sh -c "cmake -S '$results/cmake-src' -B build > /dev/null && cmake --build build > /dev/null && cp build/first a.out"
fi

# Idempotent: the same files again.
if bash "$ROOT/scripts/install-virtuose-api.sh" --no-build > "$results/install2.txt" 2> "$results/install2.err" \
   && cmp -s "$results/install.txt" "$results/install2.txt"; then
  ok "a second install succeeds and lists the same $(wc -l < "$results/install2.txt") files"
else
  nok "a second install: $(tail -2 "$results/install2.err")"
fi
exit 0
