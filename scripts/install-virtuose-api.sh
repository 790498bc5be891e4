#!/usr/bin/env bash
# Install the VirtuoseAPI client library (userspace/virtuose_api) the way
# applications written for Haption's library find it:
#  - headers: VirtuoseAPI.h and virtuoseAPI.h (Haption's two spellings; the
#    second includes the first) and virtuose_api.h (hapticctrl's extensions);
#  - the library under Haption's names, each a shared object with its own
#    soname, linked from the same static archive, exporting only the virt*
#    functions: libvirtuose.so.4 (-lvirtuose), libVirtuoseAPI.so.4
#    (-lVirtuoseAPI), libvirtuoseDLL.so.4 (-lvirtuoseDLL, the name of
#    Haption's Windows DLL), each with its .so link, and virtuoseAPI.so
#    (soname virtuoseAPI.so, as linked with -l:virtuoseAPI.so or by path);
#    the static archives libvirtuose.a, libVirtuoseAPI.a, libvirtuoseDLL.a
#    (links to libvirtuose_api.a);
#    hapticctrl's own libvirtuose_api.so and libvirtuose_api.a;
#  - pkg-config: virtuose.pc (cflags, -lvirtuose; --static adds what the
#    archive needs), relocatable (paths from ${pcfiledir});
#  - CMake: find_package(VirtuoseAPI) (LIBDIR/cmake/VirtuoseAPI/),
#    imported targets VirtuoseAPI::VirtuoseAPI (shared) and
#    VirtuoseAPI::static, and VIRTUOSE_INCLUDE_DIRS / VIRTUOSE_LIBRARIES,
#    relocatable (paths from the config file's own place).
#   scripts/install-virtuose-api.sh --prefix DIR [--destdir DIR] [--libdir REL]
#                                   [--no-build]
# --prefix: the installed prefix (default /usr/local); --destdir: a staging
# root the files go under (DESTDIR, as in `make install DESTDIR=...`);
# --libdir: the library directory relative to the prefix (default lib);
# --no-build: use userspace/target/release as it is (else cargo builds it).
# Prints the installed files.
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
prefix=/usr/local; destdir=""; libdir=lib; build=1
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix=${2:-}; shift ;;
    --destdir) destdir=${2:-}; shift ;;
    --libdir) libdir=${2:-}; shift ;;
    --no-build) build=0 ;;
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
install -d "$inc" "$lib/pkgconfig" "$lib/cmake/VirtuoseAPI"
install -m 644 "$HAP_ROOT/include/VirtuoseAPI.h" "$HAP_ROOT/include/virtuoseAPI.h" "$HAP_ROOT/include/virtuose_api.h" "$inc/"
install -m 644 "$rel/libvirtuose_api.a" "$lib/"
install -m 755 "$rel/libvirtuose_api.so" "$lib/"

# One shared object per name, with its own soname: exported are the virt*
# functions only (the Rust runtime inside stays local).
map=$(mktemp)
trap 'rm -f "$map"' EXIT
printf '{\n  global: virt*;\n  local: *;\n};\n' >"$map"
relink() { # FILE SONAME
  cc -shared -o "$lib/$1" -Wl,-soname,"$2" -Wl,--version-script="$map" -Wl,--gc-sections -Wl,--strip-debug \
    -Wl,--whole-archive "$rel/libvirtuose_api.a" -Wl,--no-whole-archive -lpthread -ldl -lm
  chmod 755 "$lib/$1"
}
for name in virtuose VirtuoseAPI virtuoseDLL; do
  relink "lib$name.so.$ABI" "lib$name.so.$ABI"
  ln -sfn "lib$name.so.$ABI" "$lib/lib$name.so"
  ln -sfn libvirtuose_api.a "$lib/lib$name.a"
done
relink virtuoseAPI.so virtuoseAPI.so

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
(cd "$root" && find include/VirtuoseAPI.h include/virtuoseAPI.h include/virtuose_api.h "$libdir" \
  \( -name '*virtuose*' -o -name '*Virtuose*' \) \( -type f -o -type l \) | sort | sed "s|^|$prefix/|")
