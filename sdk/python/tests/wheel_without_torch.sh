#!/usr/bin/env bash
# The Python package as a robot computer installs it: `pip wheel sdk/python` without the torch
# feature, installed into a fresh virtualenv that has numpy but no torch, then
# examples/python/plan_and_run.py run against it, and the torch backend refused with a hint.
# Run by `sdk/dev.sh test` with the python3 of its virtualenv (which has maturin); the fresh
# virtualenv gets numpy from PyPI.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
python=${PYTHON:-python3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { printf 'wheel_without_torch: FAILED: %s\n' "$*" >&2; exit 1; }
unset LIBTORCH LIBTORCH_USE_PYTORCH LD_LIBRARY_PATH
# The build backend runs the `maturin` program next to that python3.
PATH="$("$python" -c 'import os, sys; print(os.path.dirname(sys.executable))'):$PATH"

# The wheel (maturin through pip; the profile of MATURIN_PEP517_ARGS, release when unset).
"$python" -m pip wheel --quiet --disable-pip-version-check --no-deps --no-build-isolation \
    -w "$work/wheels" "$root/sdk/python"
wheel=$(ls "$work"/wheels/human2nav-*.whl)
printf 'wheel_without_torch: %s, %s bytes\n' "$(basename "$wheel")" "$(stat -c %s "$wheel")"

# A fresh virtualenv from the base interpreter, not the one torch lives in.
base=$("$python" -c 'import sys; print(sys.base_prefix)')
"$base/bin/python3" -m venv "$work/venv"
venv="$work/venv/bin/python3"
"$venv" -m pip install --quiet --disable-pip-version-check "numpy>=1.22" "$wheel"
if "$venv" -c 'import torch' 2>/dev/null; then fail "the fresh virtualenv has torch"; fi
"$venv" -c 'import human2nav, pathlib; print("wheel_without_torch: imported from", pathlib.Path(human2nav.__file__).parent)'

so=$(ls "$work"/venv/lib/python3*/site-packages/human2nav/_human2nav*.so)
if readelf -d "$so" | grep -E 'NEEDED|RPATH|RUNPATH' | grep -Ei 'torch|c10'; then
    fail "$so links libtorch"
fi

out=$(cd "$work" && "$venv" "$root/examples/python/plan_and_run.py" 2>&1) || {
    printf '%s\n' "$out"
    fail "examples/python/plan_and_run.py failed"
}
grep -qF "Human2Nav:" <<<"$out" || { printf '%s\n' "$out"; fail "the example did not plan"; }
printf 'wheel_without_torch: the example ran:\n%s\n' "$out"

"$venv" - "$root" <<'PY'
import sys
from pathlib import Path

import human2nav

root = Path(sys.argv[1])
robot = human2nav.RobotProfile.load(root / "robots" / "diablo" / "robot.toml")
try:
    human2nav.Human2NavPlanner(robot, root / "models" / "human2nav-cfm", backend="torch")
except ValueError as e:
    assert "--features torch" in str(e), str(e)
    print("wheel_without_torch: the torch backend is refused:", e)
else:
    raise SystemExit("wheel_without_torch: FAILED: the torch backend loaded without torch")
PY
