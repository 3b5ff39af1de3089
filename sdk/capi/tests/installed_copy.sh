#!/usr/bin/env bash
# The C library as an integrator ships it: built alone (no libtorch), installed to a prefix with
# sdk/capi/install.sh, then the C example built against the installed copy with pkg-config and
# both examples with CMake (examples/cmake), all run with nothing of libtorch on the library
# path. Run by `sdk/dev.sh test`; needs cc, c++, pkg-config and cmake.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { printf 'installed_copy: FAILED: %s\n' "$*" >&2; exit 1; }

# No PyTorch in the environment of the build or the programs.
unset LIBTORCH LIBTORCH_USE_PYTORCH LD_LIBRARY_PATH
prefix="$work/prefix"
"$root/sdk/capi/install.sh" --prefix "$prefix" --profile dev

lib="$prefix/lib/libhuman2nav_c.so"
if readelf -d "$lib" | grep -E 'NEEDED|RPATH|RUNPATH' | grep -Ei 'torch|c10|cuda|gomp'; then
    fail "$lib links libtorch"
fi

share="$prefix/share/human2nav"
args=("$share/robots/diablo/robot.toml" "$share/configs/planner.toml" "$share/models/human2nav-cfm")

check_run() { # name exe expected-substring...
    local name=$1 exe=$2
    shift 2
    if ldd "$exe" | grep -Ei 'torch|c10'; then fail "$name resolves libtorch"; fi
    local out
    out=$("$exe" "${args[@]}" 2>&1) || { printf '%s\n' "$out"; fail "$name exited with an error"; }
    for want in "$@"; do
        grep -qF -- "$want" <<<"$out" || { printf '%s\n' "$out"; fail "$name did not print \`$want\`"; }
    done
    printf 'installed_copy: %s ok\n' "$name"
}

# pkg-config: what a Makefile or meson build does.
export PKG_CONFIG_PATH="$prefix/lib/pkgconfig"
# shellcheck disable=SC2046
${CC:-cc} -std=c11 -Wall -Wextra -Werror -pedantic $(pkg-config --cflags human2nav) \
    "$root/examples/c/plan.c" $(pkg-config --libs human2nav) -lm -o "$work/plan-pkgconfig"
check_run "C example (pkg-config)" "$work/plan-pkgconfig" "plan: 33 poses 0.10 s apart" "plan within 5 ms:"

# CMake: what a C++ or ROS 2 (ament) package does.
cmake -S "$root/examples/cmake" -B "$work/build" -DCMAKE_PREFIX_PATH="$prefix" \
    -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$work/build" >/dev/null
check_run "C example (CMake)" "$work/build/plan" "plan: 33 poses 0.10 s apart"
check_run "C++ example (CMake)" "$work/build/nav2_style_controller" "reached the end of the path"

# Asking this library for the torch backend is refused, saying how to get a build with it.
sed 's/^backend = .*$//' "$share/configs/planner.toml" >"$work/torch.toml"
sed -i '1i backend = "torch"' "$work/torch.toml"
if out=$("$work/build/plan" "${args[0]}" "$work/torch.toml" "${args[2]}" 2>&1); then
    fail "the C example planned on the torch backend without libtorch"
fi
grep -qF -- '--features torch' <<<"$out" || { printf '%s\n' "$out"; fail "no hint at --features torch"; }
printf 'installed_copy: the torch backend is refused: %s\n' "$(grep -F 'backend' <<<"$out" | head -n 1)"
