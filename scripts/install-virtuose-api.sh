#!/usr/bin/env bash
# Install the VirtuoseAPI client library (userspace/virtuose_api) the way
# applications written for Haption's library find it:
#  - headers: VirtuoseAPI.h and virtuoseAPI.h (Haption's two spellings; the
#    second includes the first), the same two under virtuose/
#    (#include <virtuose/virtuoseAPI.h>), and virtuose_api.h (hapticctrl's
#    extensions);
#  - the library under Haption's names, each a shared object with its own
#    soname, linked from the same static archive, exporting only the virt*
#    functions (virtCallDLL too: the entry point of Haption's 3.x headers):
#    libvirtuose.so.4 (-lvirtuose), libVirtuoseAPI.so.4 (-lVirtuoseAPI),
#    libvirtuoseDLL.so.4 (-lvirtuoseDLL, the name of Haption's Windows
#    DLL), each with its .so link; virtuoseAPI.so (-l:virtuoseAPI.so, or by
#    path), a link to libvirtuose.so.4, so that what such a program needs at
#    run time is libvirtuose.so.4, which the loader's cache finds;
#    the static archives libvirtuose.a, libVirtuoseAPI.a, libvirtuoseDLL.a
#    (links to libvirtuose_api.a);
#    hapticctrl's own libvirtuose_api.so and libvirtuose_api.a;
#  - the layout CHAI3D 3.2's makefiles expect with VIRTUOSE_DIR set to the
#    prefix: PREFIX/include/virtuoseAPI.h and
#    PREFIX/lib/lin-<arch>/virtuoseAPI.so (a link);
#  - pkg-config: virtuose.pc (cflags, -lvirtuose; --static adds what the
#    archive needs), relocatable (paths from ${pcfiledir});
#  - CMake: find_package(VirtuoseAPI) (LIBDIR/cmake/VirtuoseAPI/),
#    imported targets VirtuoseAPI::VirtuoseAPI (shared) and
#    VirtuoseAPI::static, and VIRTUOSE_INCLUDE_DIRS / VIRTUOSE_LIBRARIES,
#    relocatable (paths from the config file's own place).
# Then, installed (no --destdir) into a directory the dynamic loader
# searches (/usr/local/lib, the default, or one of /etc/ld.so.conf's), it
# runs ldconfig (as root; otherwise it says to), so that a program linked
# with -lvirtuose starts with no further step; for any other directory it
# prints what to set (LD_LIBRARY_PATH, an rpath, or an ld.so.conf entry).
#   scripts/install-virtuose-api.sh [--prefix DIR] [--destdir DIR] [--libdir REL]
#                                   [--no-build] [--no-ldconfig]
# --prefix: the installed prefix (default /usr/local); --destdir: a staging
# root the files go under (DESTDIR, as in `make install DESTDIR=...`; no
# ldconfig then); --libdir: the library directory relative to the prefix
# (default lib); --no-build: use userspace/target/release as it is (else
# cargo builds it); --no-ldconfig: do not run ldconfig.
# Prints the installed files (on stdout), what it did about the loader (on
# stderr).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
prefix=/usr/local; destdir=""; libdir=lib; build=1; ldconf=1
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix=${2:-}; shift ;;
    --destdir) destdir=${2:-}; shift ;;
    --libdir) libdir=${2:-}; shift ;;
    --no-build) build=0 ;;
    --no-ldconfig) ldconf=0 ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (try --help)" ;;
  esac
  shift
done
case "$prefix" in /*) ;; *) die "--prefix must be an absolute path, got '$prefix'" ;; esac
case "$libdir" in ""|/*|*..*) die "--libdir must be a path relative to the prefix, got '$libdir'" ;; esac
[ -z "$destdir" ] || case "$destdir" in /*) ;; *) destdir=$(pwd)/$destdir ;; esac
VERSION=$(sed -n 's/^version = "\(.*\)"/\1/p' "$HAP_ROOT/userspace/virtuose_api/Cargo.toml" | head -1)
# The soname's version: the VirtuoseAPI major version the declarations follow.
ABI=4

rel=$HAP_ROOT/userspace/target/release
if [ "$build" = 1 ]; then
  log "cargo build --release -p virtuose_api"
  (cd "$HAP_ROOT/userspace" && cargo build --release --quiet -p virtuose_api)
fi
for f in libvirtuose_api.a libvirtuose_api.so; do
  [ -f "$rel/$f" ] || die "$rel/$f missing (build without --no-build)"
done

root=$destdir$prefix
inc=$root/include
lib=$root/$libdir
install -d "$inc/virtuose" "$lib/pkgconfig" "$lib/cmake/VirtuoseAPI"
install -m 644 "$HAP_ROOT/include/VirtuoseAPI.h" "$HAP_ROOT/include/virtuoseAPI.h" "$HAP_ROOT/include/virtuose_api.h" "$inc/"
install -m 644 "$HAP_ROOT/include/virtuose/VirtuoseAPI.h" "$HAP_ROOT/include/virtuose/virtuoseAPI.h" "$inc/virtuose/"
install -m 644 "$rel/libvirtuose_api.a" "$lib/"
install -m 755 "$rel/libvirtuose_api.so" "$lib/"

# One shared object per name, with its own soname: exported are the virt*
# functions only (the Rust runtime inside stays local). Its own calls are
# bound to its own definitions (-Bsymbolic-functions): an application built
# with Haption's 3.x header defines virt* wrappers of the same names that
# call virtCallDLL, and must not receive the library's internal calls.
map=$(mktemp)
trap 'rm -f "$map"' EXIT
printf '{\n  global: virt*;\n  local: *;\n};\n' >"$map"
relink() { # FILE SONAME
  cc -shared -o "$lib/$1" -Wl,-soname,"$2" -Wl,--version-script="$map" -Wl,-Bsymbolic-functions \
    -Wl,--gc-sections -Wl,--strip-debug \
    -Wl,--whole-archive "$rel/libvirtuose_api.a" -Wl,--no-whole-archive -lpthread -ldl -lm
  chmod 755 "$lib/$1"
}
for name in virtuose VirtuoseAPI virtuoseDLL; do
  relink "lib$name.so.$ABI" "lib$name.so.$ABI"
  ln -sfn "lib$name.so.$ABI" "$lib/lib$name.so"
  ln -sfn libvirtuose_api.a "$lib/lib$name.a"
done
# virtuoseAPI.so: a name the loader's cache does not hold (ldconfig keeps
# lib*.so* only), so it is a link to libvirtuose.so.4, whose soname is what
# a program linked with -l:virtuoseAPI.so then needs.
rm -f "$lib/virtuoseAPI.so"
ln -s libvirtuose.so.$ABI "$lib/virtuoseAPI.so"

# CHAI3D 3.2's makefiles (VIRTUOSE_DIR, default external/virtuose) compile
# with -I$VIRTUOSE_DIR/include and link -l:virtuoseAPI.so from
# $VIRTUOSE_DIR/lib/lin-x86_64: with VIRTUOSE_DIR=PREFIX they find these.
arch=$(cc -dumpmachine 2>/dev/null | cut -d- -f1); arch=${arch:-$(uname -m)}
chai=$root/lib/lin-$arch
install -d "$chai"
rm -f "$chai/virtuoseAPI.so"
ln -s "$(realpath --relative-to="$chai" "$lib")/libvirtuose.so.$ABI" "$chai/virtuoseAPI.so"

# Paths of the prefix and the include directory as seen from the pkg-config
# and CMake files (relocatable: DESTDIR staging and the package alike).
up() { local d=$1 r=""; while [ -n "$d" ] && [ "$d" != . ]; do r="../$r"; d=$(dirname "$d"); done; echo "${r%/}"; }
pc_up=$(up "$libdir/pkgconfig")
cmake_up=$(up "$libdir/cmake/VirtuoseAPI")
cat >"$lib/pkgconfig/virtuose.pc" <<EOF
prefix=\${pcfiledir}/$pc_up
includedir=\${prefix}/include
libdir=\${prefix}/$libdir

Name: virtuose
Description: Haption's VirtuoseAPI on the hapticctrl haptic controller (libvirtuose)
Version: $VERSION
Cflags: -I\${includedir}
Libs: -L\${libdir} -lvirtuose
Libs.private: -lpthread -ldl -lm
EOF
cat >"$lib/cmake/VirtuoseAPI/VirtuoseAPIConfig.cmake" <<EOF
# hapticctrl's VirtuoseAPI (Haption's API on the hapticctrl controller).
#   find_package(VirtuoseAPI)
#   target_link_libraries(app VirtuoseAPI::VirtuoseAPI)   # or VirtuoseAPI::static
# Also sets VIRTUOSE_FOUND, VIRTUOSE_INCLUDE_DIRS, VIRTUOSE_LIBRARIES.
get_filename_component(_virtuose_prefix "\${CMAKE_CURRENT_LIST_DIR}/$cmake_up" ABSOLUTE)
set(_virtuose_libdir "\${_virtuose_prefix}/$libdir")
if(NOT TARGET VirtuoseAPI::VirtuoseAPI)
  add_library(VirtuoseAPI::VirtuoseAPI SHARED IMPORTED)
  set_target_properties(VirtuoseAPI::VirtuoseAPI PROPERTIES
    IMPORTED_LOCATION "\${_virtuose_libdir}/libvirtuose.so.$ABI"
    IMPORTED_SONAME "libvirtuose.so.$ABI"
    INTERFACE_INCLUDE_DIRECTORIES "\${_virtuose_prefix}/include")
  add_library(VirtuoseAPI::static STATIC IMPORTED)
  set_target_properties(VirtuoseAPI::static PROPERTIES
    IMPORTED_LOCATION "\${_virtuose_libdir}/libvirtuose.a"
    IMPORTED_LINK_INTERFACE_LANGUAGES "C"
    INTERFACE_INCLUDE_DIRECTORIES "\${_virtuose_prefix}/include"
    INTERFACE_LINK_LIBRARIES "pthread;dl;m")
endif()
set(VIRTUOSE_FOUND TRUE)
set(VIRTUOSE_INCLUDE_DIRS "\${_virtuose_prefix}/include")
set(VIRTUOSE_LIBRARIES VirtuoseAPI::VirtuoseAPI)
set(VirtuoseAPI_VERSION "$VERSION")
unset(_virtuose_prefix)
unset(_virtuose_libdir)
EOF
cat >"$lib/cmake/VirtuoseAPI/VirtuoseAPIConfigVersion.cmake" <<EOF
set(PACKAGE_VERSION "$VERSION")
if(PACKAGE_FIND_VERSION VERSION_GREATER PACKAGE_VERSION)
  set(PACKAGE_VERSION_COMPATIBLE FALSE)
else()
  set(PACKAGE_VERSION_COMPATIBLE TRUE)
  if(PACKAGE_FIND_VERSION STREQUAL PACKAGE_VERSION)
    set(PACKAGE_VERSION_EXACT TRUE)
  endif()
endif()
EOF
chmod 644 "$lib/pkgconfig/virtuose.pc" "$lib/cmake/VirtuoseAPI/"*.cmake
(cd "$root" && find include/VirtuoseAPI.h include/virtuoseAPI.h include/virtuose_api.h include/virtuose \
  "$libdir" "lib/lin-$arch" \( -name '*virtuose*' -o -name '*Virtuose*' \) \( -type f -o -type l \) | sort -u | sed "s|^|$prefix/|")

# The dynamic loader: a program linked with -lvirtuose needs libvirtuose.so.4
# at run time.
[ -z "$destdir" ] && [ "$ldconf" = 1 ] || exit 0
real_lib=$(realpath "$lib")
searched=0
while read -r d; do
  [ -n "$d" ] && [ "$(realpath "$d" 2>/dev/null)" = "$real_lib" ] && searched=1
done < <(ldconfig -v -N -X 2>/dev/null | sed -n 's|^\(/[^:]*\):.*|\1|p')
if [ "$searched" = 1 ]; then
  if [ "$(id -u)" = 0 ]; then
    ldconfig
    found=$(ldconfig -p | awk -v w="$real_lib/libvirtuose.so.$ABI" -v n="libvirtuose.so.$ABI" '$1 == n && $NF == w { f = $NF } END { print f }')
    [ -n "$found" ] || die "ldconfig ran but its cache has no libvirtuose.so.$ABI in $lib"
    echo "ldconfig: the loader finds libvirtuose.so.$ABI in $lib: programs linked with -lvirtuose start as they are" >&2
  else
    echo "note: run 'sudo ldconfig' once so that programs linked with -lvirtuose find libvirtuose.so.$ABI in $lib" >&2
  fi
else
  cat >&2 <<EOF
note: $lib is not a directory the dynamic loader searches. A program
linked with -lvirtuose (or -lVirtuoseAPI, -l:virtuoseAPI.so) starts with one of:
  LD_LIBRARY_PATH=$lib ./app                    (each run)
  cc app.c -L$lib -Wl,-rpath,$lib -lvirtuose    (at link time)
  echo $lib > /etc/ld.so.conf.d/virtuose.conf && ldconfig   (as root, once for every program)
EOF
fi
