#!/usr/bin/env bash
# One entry point for a fresh machine: installs what human2nav needs, then runs a job.
#
#   sdk/dev.sh demo [ARGS...]   the main job (see README.md)
#   sdk/dev.sh test             build everything and run the whole test suite
#   sdk/dev.sh python           install the Python package `human2nav` (sdk/python) into the
#                               torch virtualenv below (`import human2nav` with its python3)
#   sdk/dev.sh env              print the exports this script uses (eval "$(sdk/dev.sh env)"),
#                               with torch and the Python tools installed
#
# libtorch comes from PyTorch 2.13.0 on PyPI (the version tch 0.26 is built against),
# installed once into a virtualenv in a cache outside the repository:
#   ${HUMAN2NAV_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/human2nav}/torch-2.13.0
# Binaries find libtorch at run time through an rpath baked in by the build scripts.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cache=${HUMAN2NAV_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/human2nav}
venv="$cache/torch-2.13.0"
torch_version=2.13.0

log() { printf '[dev.sh] %s\n' "$*" >&2; }

torch_ready() {
    [ -x "$venv/bin/python3" ] &&
        "$venv/bin/python3" -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$torch_version')" 2>/dev/null
}

ensure_torch() {
    torch_ready && return
    command -v python3 >/dev/null || { log "python3 is required to install PyTorch"; exit 1; }
    mkdir -p "$cache"
    # Two runs on a fresh machine: the second waits on the lock for the first's install and
    # then finds it done. Without flock, each installs into a folder of its own and the first
    # to finish renames it into place (a rename onto a non-empty folder fails; the later one
    # then discards its copy).
    if command -v flock >/dev/null; then
        exec 9>"$venv.lock"
        if ! flock -n 9; then
            log "another run is installing PyTorch into $venv; waiting for it"
            flock 9
        fi
        if torch_ready; then
            exec 9>&-
            return
        fi
        rm -rf "$venv".partial.* # left by runs that were killed (none runs: we hold the lock)
    fi
    log "installing PyTorch $torch_version from PyPI into $venv (one time, about 5 GB)"
    # A venv left by an older or broken install (the check above failed on it).
    [ -e "$venv" ] && rm -rf "$venv"
    local partial="$venv.partial.$$"
    rm -rf "$partial"
    python3 -m venv "$partial"
    "$partial/bin/pip" install --quiet --disable-pip-version-check "torch==$torch_version"
    if python3 -c 'import os, sys; os.rename(sys.argv[1], sys.argv[2])' "$partial" "$venv" 2>/dev/null; then
        # A venv's scripts name their own path; re-create them at the final location.
        python3 -m venv --upgrade "$venv" >/dev/null
    else
        log "another run installed $venv first; using it"
        rm -rf "$partial"
    fi
    exec 9>&-
}

ensure_python_tools() {
    # The Python package's build backend, its runtime dependency and its test runner, in the
    # same virtualenv as torch (the package links that torch's libtorch); the readers and
    # writers of MCAP files and ROS 2 bags the tests check the recordings and replays with;
    # and CMake, which the test of the installed C library builds the examples with.
    if ! "$venv/bin/python3" -c "import maturin, numpy, pytest, mcap, rosbags, cmake" 2>/dev/null; then
        log "installing maturin, numpy, pytest, mcap, rosbags and cmake into $venv"
        "$venv/bin/python3" -m pip install --quiet --disable-pip-version-check \
            "maturin>=1.7,<2" "numpy>=1.22" "pytest>=7" "mcap>=1.1,<2" "rosbags>=0.10,<0.12" \
            "cmake>=3.16,<5"
    fi
}

# Builds and installs sdk/python into the virtualenv, with the torch backend (the `torch`
# feature; a plain `pip install sdk/python` or `pip wheel sdk/python` needs no torch). No build
# isolation: torch-sys finds libtorch through the virtualenv's torch (LIBTORCH_USE_PYTORCH=1).
install_python_package() {
    ensure_python_tools
    MATURIN_PEP517_ARGS="${MATURIN_PEP517_ARGS:-} --features torch" \
        "$venv/bin/python3" -m pip install --quiet --disable-pip-version-check \
        --no-build-isolation --force-reinstall --no-deps "$root/sdk/python"
}

ensure_fonts() {
    # plotters draws text through fontconfig; a minimal machine may lack both.
    if ! command -v fc-list >/dev/null || [ -z "$(fc-list 2>/dev/null | head -n 1)" ] ||
        ! pkg-config --exists fontconfig 2>/dev/null; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            log "installing fontconfig and DejaVu fonts (for figures)"
            apt-get update -qq && apt-get install -y -qq libfontconfig1-dev fonts-dejavu-core pkg-config >/dev/null
        else
            log "warning: fontconfig or fonts are missing; install libfontconfig1-dev and a TTF font"
        fi
    fi
}

setup() {
    ensure_torch
    ensure_fonts
    export LIBTORCH_USE_PYTORCH=1
    export PATH="$venv/bin:$PATH"
    cd "$root"
}

case "${1:-}" in
    demo)
        shift
        setup
        cargo build --release --workspace
        bin="$root/target/release/human2nav"
        "$bin" robot check robots/*/robot.toml
        # One planning step of the shipped model on a synthetic crowd, drawn like Fig. 4.
        "$bin" plan --robot robots/diablo/robot.toml --out out/demo/plan-diablo.png "$@"
        echo "picture: out/demo/plan-diablo.png"
        # The closed-loop benchmark, a few episodes per scenario class: real held-out crowds
        # when ../shared/data (or $HUMAN2NAV_DATA) is there, else the synthetic crowd.
        "$bin" bench --config sdk/configs/bench.toml --quick --out out/bench-quick
        echo "report: out/bench-quick/report.md; every episode: target/release/human2nav bench --config sdk/configs/bench.toml"
        ;;
    test)
        setup
        # All targets in one build: the tests' dev-dependencies unify features (serde, syn,
        # tch, ...) differently from a build of the libraries alone, which compiled most of
        # the dependency graph twice. The plugin libraries the tests load are built here too.
        cargo build --workspace --all-targets
        cargo test --workspace
        # The API documentation builds without a warning (broken links, stray HTML).
        RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps
        # Planning without libtorch: the flow crate's own tests without its `torch` feature,
        # the C library installed to a prefix and used from C and C++ (pkg-config, CMake), and
        # the Python wheel in a virtualenv without torch.
        cargo test -p human2nav-flow --lib
        ensure_python_tools
        sdk/capi/tests/installed_copy.sh
        MATURIN_PEP517_ARGS="--profile dev" PYTHON="$venv/bin/python3" \
            sdk/python/tests/wheel_without_torch.sh
        # The Python package, built with the test build's profile (sharing its artifacts).
        MATURIN_PEP517_ARGS="--profile dev" install_python_package
        exec "$venv/bin/python3" -m pytest -q "$root/sdk/python/tests"
        ;;
    python)
        setup
        install_python_package
        log "installed: $venv/bin/python3 -c 'import human2nav'"
        ;;
    env)
        # The Python tools too: the PyTorch references (sdk/flow/reference) read with numpy.
        { setup; ensure_python_tools; } >&2
        printf 'export LIBTORCH_USE_PYTORCH=1\nexport PATH=%q:"$PATH"\n' "$venv/bin"
        ;;
    *)
        sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'
        exit 2
        ;;
esac
