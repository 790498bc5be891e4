#!/usr/bin/env bash
# VirtuoseAPI applications' build and run conventions against the installed
# layout: stages scripts/install-virtuose-api.sh (DESTDIR, prefix /usr,
# Debian's multiarch libdir, as in the tools package), builds
# tests/vapi/apps.c with #include "virtuoseAPI.h" and each way Haption's
# applications link the library (-lvirtuose, -lVirtuoseAPI, -lvirtuoseDLL,
# -l:virtuoseAPI.so, pkg-config virtuose, the static archive, CMake's
# find_package(VirtuoseAPI) shared and static, and as C++), with
# <virtuose/virtuoseAPI.h>, with CHAI3D 3.2's VIRTUOSE_DIR flags, and with a
# header of the form of Haption's 3.x releases shipped next to the
# application's sources (tests/vapi/haption3/: every virt* a wrapper that
# calls virtCallDLL; C, C++, and 3.80's int result), checks what each
# binary needs at run time, and runs each against the fake controller
# (virtuose_api's fake_controller, answers lagging a power request by 200
# cycles; the handle's buttons pressed as given, so buttons 1 and 2 are
# seen pressed and released); each program then checks that calls on its
# closed context and on never-opened ones fail with VIRT_E_INVALID_CONTEXT
# within a second.
# Then the default install (tests/vapi/default-install.sh): the script with
# no argument, ldconfig, and `cc first.c -lvirtuose` started with no
# LD_LIBRARY_PATH, in a private mount namespace (unshare -m) where
# /usr/local and /etc are overlays, so nothing outside changes; when no
# namespace can be made and this is root, on the host's /usr/local (kept;
# a second run replaces the same files).
#   tests/vapi/run.sh [--results DIR] [--ms N]
# --ms: the length of each of the program's two callback-loop phases
# (default 300). Installs Debian's pkg-config and cmake when missing (root).
# Prints every check, then "vapi-apps: N passed, N failed".
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
results=""; ms=300
while [ $# -gt 0 ]; do
  case "$1" in
    --results) results=${2:-}; shift ;;
    --ms) ms=${2:-}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
[[ "$ms" =~ ^[0-9]+$ ]] && [ "$ms" -ge 100 ] || die "--ms: a number of ms >= 100, got '$ms'"
results=${results:-$ROOT/build/vapi-apps}
mkdir -p "$results"; rm -rf "${results:?}"/*

pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
finish() { echo "vapi-apps: $pass passed, $fail failed"; [ "$fail" = 0 ]; exit $?; }

# The build tools the applications use: pkg-config and CMake (Debian's).
missing=()
command -v pkg-config >/dev/null || missing+=(pkg-config)
command -v cmake >/dev/null || missing+=(cmake)
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    log "installing Debian's ${missing[*]}"
    apt-get install -y --no-install-recommends -o DPkg::Lock::Timeout=600 "${missing[@]}" > "$results/apt.log" 2>&1 \
      || { apt-get update -q > /dev/null 2>&1 && apt-get install -y --no-install-recommends -o DPkg::Lock::Timeout=600 "${missing[@]}" >> "$results/apt.log" 2>&1; } \
      || { tail -5 "$results/apt.log"; nok "install ${missing[*]}"; }
  else
    echo "# ${missing[*]} not installed and this is not root (apt-get install ${missing[*]})"
  fi
fi

(cd "$ROOT/userspace" && cargo build --release --quiet -p virtuose_api --lib --example fake_controller) \
  || { nok "build libvirtuose_api and the fake controller"; finish; }
fc="$ROOT/userspace/target/release/examples/fake_controller"

# ---- the installed layout, staged
stage="$results/stage"
libdir=lib/$(gcc -print-multiarch 2>/dev/null || echo x86_64-linux-gnu)
if bash "$ROOT/scripts/install-virtuose-api.sh" --prefix /usr --libdir "$libdir" --destdir "$stage" --no-build > "$results/install.txt" 2> "$results/install.err"; then
  ok "install-virtuose-api.sh staged $(wc -l < "$results/install.txt") files under DESTDIR"
else
  sed 's/^/# /' "$results/install.err" | tail -5; nok "install-virtuose-api.sh"; finish
fi
inc="$stage/usr/include"
lib="$stage/usr/$libdir"
arch=$(cc -dumpmachine | cut -d- -f1)
for f in include/VirtuoseAPI.h include/virtuoseAPI.h include/virtuose/virtuoseAPI.h include/virtuose/VirtuoseAPI.h \
         "$libdir/libvirtuose.so" "$libdir/libVirtuoseAPI.so" \
         "$libdir/libvirtuoseDLL.so" "$libdir/virtuoseAPI.so" "$libdir/libvirtuose.a" "$libdir/pkgconfig/virtuose.pc" \
         "$libdir/cmake/VirtuoseAPI/VirtuoseAPIConfig.cmake" "lib/lin-$arch/virtuoseAPI.so"; do
  [ -e "$stage/usr/$f" ] && ok "installed /usr/$f" || nok "not installed: /usr/$f"
done
soname() { readelf -d "$1" 2>/dev/null | sed -n 's/.*(SONAME).*\[\(.*\)\]/\1/p'; }
for f in libvirtuose.so.4 libVirtuoseAPI.so.4 libvirtuoseDLL.so.4; do
  [ "$(soname "$lib/$f")" = "$f" ] && ok "$f has soname $f" || nok "$f: soname '$(soname "$lib/$f")'"
done
# virtuoseAPI.so and CHAI3D's lib/lin-ARCH/virtuoseAPI.so: links to
# libvirtuose.so.4 (a name the loader's cache holds).
for f in "$lib/virtuoseAPI.so" "$stage/usr/lib/lin-$arch/virtuoseAPI.so"; do
  [ -L "$f" ] && [ "$(readlink -f "$f")" = "$(readlink -f "$lib/libvirtuose.so.4")" ] \
    && ok "${f#"$stage"} links to libvirtuose.so.4" || nok "${f#"$stage"}: $(ls -l "$f" 2>&1)"
done
n=$(nm -D --defined-only "$lib/libvirtuose.so.4" | awk '$2 == "T" && $3 ~ /^virt/' | wc -l)
other=$(nm -D --defined-only "$lib/libvirtuose.so.4" | awk '$2 == "T" && $3 !~ /^virt/' | wc -l)
[ "$n" -ge 120 ] && [ "$other" = 0 ] && ok "libvirtuose.so.4 exports the $n virt* functions and nothing else" || nok "libvirtuose.so.4 exports $n virt* and $other other functions"
nm -D --defined-only "$lib/libvirtuose.so.4" | grep -c ' T virtCallDLL$' | grep -qx 1 && ok "libvirtuose.so.4 exports virtCallDLL (Haption's 3.x entry point)" || nok "virtCallDLL not exported"

# ---- build apps.c as the applications' build files do
src="$ROOT/tests/vapi/apps.c"
cflags=(-O1 -Wall -Wextra -Werror)
declare -A built=()
build() { # NAME NEEDED(expected, or "-" for static) COMMAND...
  local name=$1 want=$2; shift 2
  if "$@" > "$results/build-$name.log" 2>&1; then
    local needed
    needed=$(readelf -d "$results/apps-$name" | sed -n 's/.*(NEEDED).*\[\(.*[Vv]irtuose.*\)\]/\1/p' | paste -sd,)
    if [ "$want" = - ]; then
      [ -z "$needed" ] && ok "$name: builds, needs no VirtuoseAPI shared object (static)" && built[$name]=1 || nok "$name: needs '$needed'"
    else
      [ "$needed" = "$want" ] && ok "$name: builds, needs $want at run time" && built[$name]=1 || nok "$name: needs '$needed', want $want"
    fi
  else
    sed 's/^/# /' "$results/build-$name.log" | head -10; nok "$name: build"
  fi
}
build lvirtuose libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" -I "$inc" "$src" -L "$lib" -lvirtuose -lm -o "$results/apps-lvirtuose"
build lVirtuoseAPI libVirtuoseAPI.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" -I "$inc" "$src" -L "$lib" -lVirtuoseAPI -lm -o "$results/apps-lVirtuoseAPI"
build lvirtuoseDLL libvirtuoseDLL.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" -I "$inc" "$src" -L "$lib" -lvirtuoseDLL -lm -o "$results/apps-lvirtuoseDLL"
build l-virtuoseAPI.so libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" -I "$inc" "$src" -L "$lib" -l:virtuoseAPI.so -lm -o "$results/apps-l-virtuoseAPI.so"
build cxx libvirtuose.so.4 c++ -x c++ "${cflags[@]}" -I "$inc" "$src" -x none -L "$lib" -lvirtuose -o "$results/apps-cxx"
build subdir libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L -DVIRTUOSE_SUBDIR "${cflags[@]}" -I "$inc" "$src" -L "$lib" -lvirtuose -lm -o "$results/apps-subdir"
# CHAI3D 3.2's makefiles with VIRTUOSE_DIR at the prefix (C++).
vdir="$stage/usr"
build chai3d libvirtuose.so.4 c++ -x c++ "${cflags[@]}" -I "$vdir/include" "$src" -x none -L "$vdir/lib/lin-$arch" -l:virtuoseAPI.so -o "$results/apps-chai3d"
# Haption's 3.x header form, next to the application's sources (first on
# the include path): the application defines every virt* itself, each
# calling virtCallDLL.
h3="$ROOT/tests/vapi/haption3"
build haption3 libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" -I "$h3" -I "$inc" "$src" -L "$lib" -lvirtuose -lm -o "$results/apps-haption3"
build haption3-cxx libvirtuose.so.4 c++ -x c++ "${cflags[@]}" -I "$h3" -I "$inc" "$src" -x none -L "$lib" -lvirtuose -o "$results/apps-haption3-cxx"
build haption3-380 libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L -DVIRTUOSE_API_380 "${cflags[@]}" -I "$h3" -I "$inc" "$src" -L "$lib" -lvirtuose -lm -o "$results/apps-haption3-380"
if [ -n "${built[haption3]:-}" ]; then
  nv=$(nm -D --defined-only "$results/apps-haption3" | awk '$3 ~ /^virt/' | wc -l)
  nm -D --undefined-only "$results/apps-haption3" | grep -c ' virtCallDLL$' | grep -qx 1 && [ "$nv" -ge 118 ] \
    && ok "haption3: the program defines its $nv virt* wrappers itself and calls the library's virtCallDLL" \
    || nok "haption3: $nv virt* defined in the program, virtCallDLL $(nm -D "$results/apps-haption3" | grep -c virtCallDLL)"
fi
if pc=$(PKG_CONFIG_PATH="$lib/pkgconfig" pkg-config --cflags --libs virtuose 2>"$results/pkg-config.err"); then
  echo "# pkg-config --cflags --libs virtuose: $pc"
  # shellcheck disable=SC2086
  build pkg-config libvirtuose.so.4 cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" "$src" $pc -lm -o "$results/apps-pkg-config"
  pcs=$(PKG_CONFIG_PATH="$lib/pkgconfig" pkg-config --static --libs-only-l virtuose | sed 's/-lvirtuose//')
  # shellcheck disable=SC2086
  build static - cc -std=c99 -D_POSIX_C_SOURCE=200809L "${cflags[@]}" "$src" $(PKG_CONFIG_PATH="$lib/pkgconfig" pkg-config --cflags virtuose) "$lib/libvirtuose.a" $pcs -lm -o "$results/apps-static"
else
  nok "pkg-config virtuose: $(cat "$results/pkg-config.err" 2>/dev/null || echo 'no pkg-config')"
fi
if command -v cmake >/dev/null; then
  cm="$results/cmake"
  mkdir -p "$cm/src"
  cat > "$cm/src/CMakeLists.txt" <<EOF
cmake_minimum_required(VERSION 3.13)
project(vapi_apps C)
find_package(VirtuoseAPI REQUIRED)
add_executable(apps-cmake "$src")
target_compile_definitions(apps-cmake PRIVATE _POSIX_C_SOURCE=200809L)
target_link_libraries(apps-cmake VirtuoseAPI::VirtuoseAPI m)
add_executable(apps-cmake-static "$src")
target_compile_definitions(apps-cmake-static PRIVATE _POSIX_C_SOURCE=200809L)
target_link_libraries(apps-cmake-static VirtuoseAPI::static m)
add_executable(apps-cmake-vars "$src")
target_compile_definitions(apps-cmake-vars PRIVATE _POSIX_C_SOURCE=200809L)
target_include_directories(apps-cmake-vars PRIVATE \${VIRTUOSE_INCLUDE_DIRS})
target_link_libraries(apps-cmake-vars \${VIRTUOSE_LIBRARIES} m)
EOF
  cmake_build() {
    cmake -S "$cm/src" -B "$cm/build" -DCMAKE_PREFIX_PATH="$stage/usr" -DCMAKE_C_STANDARD=99 >/dev/null &&
      cmake --build "$cm/build" >/dev/null &&
      cp "$cm/build/apps-cmake" "$results/apps-cmake" && cp "$cm/build/apps-cmake-static" "$results/apps-cmake-static" &&
      cp "$cm/build/apps-cmake-vars" "$results/apps-cmake-vars"
  }
  if cmake_build > "$results/build-cmake.log" 2>&1; then
    for n in cmake cmake-vars; do
      needed=$(readelf -d "$results/apps-$n" | sed -n 's/.*(NEEDED).*\[\(.*[Vv]irtuose.*\)\]/\1/p')
      [ "$needed" = libvirtuose.so.4 ] && { ok "$n: find_package(VirtuoseAPI) builds, needs libvirtuose.so.4"; built[$n]=1; } || nok "$n: needs '$needed'"
    done
    needed=$(readelf -d "$results/apps-cmake-static" | sed -n 's/.*(NEEDED).*\[\(.*[Vv]irtuose.*\)\]/\1/p')
    [ -z "$needed" ] && { ok "cmake-static: VirtuoseAPI::static builds, needs no VirtuoseAPI shared object"; built[cmake-static]=1; } || nok "cmake-static: needs '$needed'"
  else
    sed 's/^/# /' "$results/build-cmake.log" | tail -10; nok "cmake: find_package(VirtuoseAPI) and build"
  fi
else
  nok "the CMake package: no cmake on this machine (apt-get install cmake)"
fi

# ---- run each against the fake controller
# buttons: each binary gets one of the four states of the two buttons.
run_one() { # NAME FIRST SECOND
  local name=$1 first=$2 second=$3 dir="$results/run-$1"
  mkdir -p "$dir"; mkfifo "$dir/fake.in"
  "$fc" --duration 30 --center 0.45,0.05,0.25 --amplitude 0.01,0,0 --power-lag 200 --buttons $((first + 2 * second)) \
    < "$dir/fake.in" > "$dir/fake.txt" 2> "$dir/fake.err" &
  local fpid=$! hold port
  exec {hold}> "$dir/fake.in"
  for _ in $(seq 100); do grep -q '^PORT ' "$dir/fake.txt" && break; sleep 0.1; done
  port=$(sed -n 's/^PORT //p' "$dir/fake.txt")
  if ! [[ "$port" =~ ^[0-9]+$ ]]; then exec {hold}>&-; wait "$fpid"; nok "$name: the fake controller did not start: $(cat "$dir/fake.err")"; return; fi
  LD_LIBRARY_PATH="$lib" timeout 60 "$results/apps-$name" "127.0.0.1#$port" "$ms" "$first" "$second" > "$dir/apps.txt" 2>&1
  local rc=$?
  exec {hold}>&-
  wait "$fpid"
  local line
  line=$(grep -E '^apps: [0-9]+ passed' "$dir/apps.txt" | tail -1)
  if [ "$rc" = 0 ] && [ -n "$line" ]; then
    ok "$name against the fake controller (buttons $first $second): ${line#apps: }"
  else
    grep -E '^not ok' "$dir/apps.txt" | sed 's/^/# /' | head -10
    nok "$name against the fake controller (exit $rc): ${line:-no summary}"
  fi
  grep -q '^session_open: 0$' "$dir/fake.txt" && grep -q '^frames.close_session: 1$' "$dir/fake.txt" \
    && ok "$name: closed its session" || nok "$name: the session was not closed"
}
k=0
for name in lvirtuose lVirtuoseAPI lvirtuoseDLL l-virtuoseAPI.so cxx subdir chai3d haption3 haption3-cxx haption3-380 \
            pkg-config static cmake cmake-static cmake-vars; do
  [ -n "${built[$name]:-}" ] || continue
  run_one "$name" $((k % 2)) $(((k / 2) % 2))
  k=$((k + 1))
done
# The program's own checks, in full, for the first run.
sed 's/^/# apps-lvirtuose: /' "$results/run-lvirtuose/apps.txt" 2>/dev/null | head -70

# ---- the default install, as a newcomer runs it
di="$ROOT/tests/vapi/default-install.sh"
if unshare -m true 2>/dev/null; then
  di_cmd=(unshare -m bash "$di" namespace)
elif unshare -rm true 2>/dev/null; then
  di_cmd=(unshare -rm bash "$di" namespace)
elif [ "$(id -u)" = 0 ]; then
  di_cmd=(bash "$di" host)
else
  di_cmd=()
fi
if [ ${#di_cmd[@]} -gt 0 ]; then
  "${di_cmd[@]}" "$results/default-install" "$fc" "$ms" > "$results/default-install.txt" 2>&1
  while IFS= read -r line; do
    case "$line" in
      "ok - "*) ok "${line#ok - }" ;;
      "not ok - "*) nok "${line#not ok - }" ;;
      *) echo "$line" ;;
    esac
  done < "$results/default-install.txt"
  grep -qE '^ok - default install: first: ' "$results/default-install.txt" || nok "default install: the first program did not run"
else
  nok "default install: neither a mount namespace (unshare -m, unshare -rm) nor root to install into /usr/local"
fi
finish
