#!/usr/bin/env bash
# Builds the planner's C library without libtorch and installs it to a prefix, ready for a C,
# C++ or ROS 2 build to find with pkg-config or CMake.
#
#   sdk/capi/install.sh --prefix DIR [--profile release|dev] [--strip] [--torch]
#
# Installs
#   DIR/lib/libhuman2nav_c.so                         the library (plans on the native backend)
#   DIR/include/human2nav.h                           its header
#   DIR/lib/pkgconfig/human2nav.pc                    pkg-config --cflags --libs human2nav
#   DIR/lib/cmake/human2nav/human2nav-config.cmake    find_package(human2nav) -> human2nav::human2nav
#   DIR/lib/cmake/human2nav/human2nav-config-version.cmake
#   DIR/share/human2nav/{robots,configs,models}       the shipped robots, planner settings and model
#
# Needs only cargo and a C linker: no PyTorch. `--torch` builds the library with the `torch`
# backend as well; it then links the libtorch of the PyTorch installation it was built against
# (run `eval "$(sdk/dev.sh env)"` first) and needs that installation at run time.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
prefix=""
profile=release
strip=false
features=()

usage() { sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; }
fail() { printf 'install.sh: %s\n' "$*" >&2; exit 2; }

while [ $# -gt 0 ]; do
    case "$1" in
        --prefix) [ $# -ge 2 ] || fail "--prefix needs a folder"; prefix=$2; shift 2 ;;
        --prefix=*) prefix=${1#--prefix=}; shift ;;
        --profile) [ $# -ge 2 ] || fail "--profile needs release or dev"; profile=$2; shift 2 ;;
        --profile=*) profile=${1#--profile=}; shift ;;
        --strip) strip=true; shift ;;
        --torch) features=(--features torch); shift ;;
        -h|--help) usage; exit 0 ;;
        *) usage >&2; fail "unknown argument \`$1\`" ;;
    esac
done
[ -n "$prefix" ] || { usage >&2; fail "--prefix is required"; }
case "$profile" in
    release) out=release ;;
    dev) out=debug ;;
    *) fail "--profile must be release or dev, not \`$profile\`" ;;
esac
mkdir -p "$prefix" || fail "cannot create the prefix $prefix"
prefix=$(cd "$prefix" && pwd)
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' "$root/Cargo.toml" | head -n 1)
[ -n "$version" ] || fail "no workspace version in $root/Cargo.toml"

cd "$root"
# This package alone, so that no other package's features (the CLI's libtorch) reach it.
cargo build --profile "$profile" -p human2nav-capi ${features[@]+"${features[@]}"}
lib="$root/target/$out/libhuman2nav_c.so"
[ -f "$lib" ] || fail "cargo did not produce $lib"

install -d "$prefix/lib/pkgconfig" "$prefix/lib/cmake/human2nav" "$prefix/include" \
    "$prefix/share/human2nav"
install -m 644 "$root/sdk/capi/include/human2nav.h" "$prefix/include/human2nav.h"
install -m 755 "$lib" "$prefix/lib/libhuman2nav_c.so"
if $strip; then
    strip --strip-unneeded "$prefix/lib/libhuman2nav_c.so"
fi

cat >"$prefix/lib/pkgconfig/human2nav.pc" <<EOF
prefix=$prefix
libdir=\${prefix}/lib
includedir=\${prefix}/include
datadir=\${prefix}/share/human2nav

Name: human2nav
Description: Crowd-navigation planner learned from human trajectories (C API)
Version: $version
Libs: -L\${libdir} -lhuman2nav_c -Wl,-rpath,\${libdir}
Libs.private: -lm
Cflags: -I\${includedir}
EOF

cat >"$prefix/lib/cmake/human2nav/human2nav-config.cmake" <<'EOF'
# find_package(human2nav) for the planner's C library: the imported target human2nav::human2nav
# (library and include folder) and HUMAN2NAV_DATA_DIR (the shipped robots, configs and model).
get_filename_component(_human2nav_prefix "${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)
if(NOT TARGET human2nav::human2nav)
  add_library(human2nav::human2nav SHARED IMPORTED)
  set_target_properties(human2nav::human2nav PROPERTIES
    IMPORTED_LOCATION "${_human2nav_prefix}/lib/libhuman2nav_c.so"
    IMPORTED_NO_SONAME TRUE
    INTERFACE_INCLUDE_DIRECTORIES "${_human2nav_prefix}/include"
    INTERFACE_LINK_LIBRARIES m)
endif()
set(HUMAN2NAV_DATA_DIR "${_human2nav_prefix}/share/human2nav")
unset(_human2nav_prefix)
EOF

cat >"$prefix/lib/cmake/human2nav/human2nav-config-version.cmake" <<EOF
# The library's version; releases before 1.0 are compatible only within the same minor version.
set(PACKAGE_VERSION "$version")
string(REGEX MATCH "^[0-9]+\\\\.[0-9]+" _human2nav_minor "\${PACKAGE_VERSION}")
string(REGEX MATCH "^[0-9]+\\\\.[0-9]+" _human2nav_wanted "\${PACKAGE_FIND_VERSION}")
if(PACKAGE_FIND_VERSION VERSION_GREATER PACKAGE_VERSION)
  set(PACKAGE_VERSION_COMPATIBLE FALSE)
elseif(PACKAGE_FIND_VERSION AND NOT _human2nav_minor STREQUAL _human2nav_wanted)
  set(PACKAGE_VERSION_COMPATIBLE FALSE)
else()
  set(PACKAGE_VERSION_COMPATIBLE TRUE)
  if(PACKAGE_FIND_VERSION STREQUAL PACKAGE_VERSION)
    set(PACKAGE_VERSION_EXACT TRUE)
  endif()
endif()
EOF

# What a planner needs at run time besides the library: robot profiles, planner settings and
# the trained model (the paths the examples take as arguments).
rm -rf "$prefix/share/human2nav/robots" "$prefix/share/human2nav/configs" \
    "$prefix/share/human2nav/models"
cp -R "$root/robots" "$prefix/share/human2nav/robots"
install -d "$prefix/share/human2nav/configs"
install -m 644 "$root/sdk/configs/planner.toml" "$prefix/share/human2nav/configs/planner.toml"
install -d "$prefix/share/human2nav/models"
cp -R "$root/models/human2nav-cfm" "$prefix/share/human2nav/models/human2nav-cfm"

printf 'installed human2nav %s to %s (%s bytes of library)\n' "$version" "$prefix" \
    "$(stat -c %s "$prefix/lib/libhuman2nav_c.so")"
