#!/usr/bin/env bash
# The Python package (userspace/hapticctrl-py): a virtual environment with
# pinned packages from PyPI (maturin, numpy, pytest, MuJoCo, matplotlib) in
# the cache, the wheel built from the source tree by pip through maturin
# (the package's own build backend), installed and imported from outside the
# tree, the bindings linted (clippy with the extension's feature), then
# pytest: the API against the authenticated fake controller
# (hapticctrl-fake) and the MuJoCo example headless against it.
#   tests/python/run.sh [--target fake|qemu] [--port N] [--results DIR]
# --target qemu: the MuJoCo example against the module in QEMU instead
# (Debian's stock kernel, module built with make STOCK=1, the authenticated
# bridge, tcg-icount; UDP 127.0.0.1:PORT -> guest:5000, --port or a free
# one): the scripted user (tests/data/press.eff) presses the handle down, the
# coupled tool meets MuJoCo's table; checked from the client's side (the
# contact force felt) and the module's position log (the coupling force at
# the handle, and its fade when the client goes silent).
# Prints every check, then "python[-qemu]: N passed, N failed" (the pytest
# count included; pytest collecting nothing counts as a failure).
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
results=""; target=fake; port=""
while [ $# -gt 0 ]; do
  case "$1" in
    --target) target=${2:-}; shift ;;
    --port) port=${2:-}; shift ;;
    --results) results=${2:-}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
case "$target" in fake|qemu) ;; *) die "--target fake or qemu, got '$target'" ;; esac
name=python; [ "$target" = qemu ] && name=python-qemu
results=${results:-$ROOT/build/$name}
mkdir -p "$results"; rm -rf "${results:?}"/*
pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
finish() { echo "$name: $pass passed, $fail failed"; [ "$fail" = 0 ]; exit $?; }
t0=$(date +%s)

. "$ROOT/scripts/python-venv.sh"
hap_python_venv "$results" || { nok "pip install -r userspace/hapticctrl-py/requirements-test.txt"; finish; }
ok "virtual environment: $("$py" --version), $(grep -v '^#' "$ROOT/userspace/hapticctrl-py/requirements-test.txt" | tr '\n' ' ')($(( $(date +%s) - t0 )) s so far)"

export CARGO_TARGET_DIR="$ROOT/userspace/target"
(cd "$ROOT/userspace" && cargo build --release --quiet -p hapticctrl-py --bin hapticctrl-fake) \
  && ok "hapticctrl-fake built" || { nok "build hapticctrl-fake"; finish; }

t_wheel=$(date +%s)
hap_python_wheel "$results" && ok "wheel built from the source tree and installed: $(basename "$whl") ($(( $(date +%s) - t_wheel )) s)" \
  || { nok "pip wheel userspace/hapticctrl-py"; finish; }
where=$(cd / && "$py" -c 'import hapticctrl, hapticctrl._native as n; print(hapticctrl.__version__, n.__file__)') \
  && ok "import hapticctrl (from /): $where" || nok "import hapticctrl"
stubs=$(cd / && "$py" -c 'import hapticctrl, pathlib; p = pathlib.Path(hapticctrl.__file__).parent; print(int((p / "_native.pyi").exists() and (p / "py.typed").exists()))')
[ "$stubs" = 1 ] && ok "type stubs installed (_native.pyi, py.typed)" || nok "type stubs missing from the wheel"
(cd "$ROOT/userspace" && PYO3_PYTHON="$py" cargo clippy --quiet -p hapticctrl-py --features python --all-targets --color never -- -D warnings) \
  && ok "clippy -D warnings on the bindings (feature python)" || nok "clippy on the bindings"

[ "$target" = qemu ] && { . "$ROOT/tests/python/qemu.sh"; finish; }

out="$results/pytest.txt"
t_pytest=$(date +%s)
(cd "$ROOT/userspace/hapticctrl-py/tests" && HAPTICCTRL_FAKE="$CARGO_TARGET_DIR/release/hapticctrl-fake" MPLBACKEND=Agg \
  "$py" -m pytest -p no:cacheprovider -q -rs --basetemp="$results/tmp" 2>&1) | tee "$out"
rc=${PIPESTATUS[0]}
line=$(grep -E '^[0-9]+ (passed|failed)|^=+ .*(passed|failed)' "$out" | tail -1)
p=$(echo "$line" | grep -oE '[0-9]+ passed' | awk '{print $1}'); p=${p:-0}
f=$(echo "$line" | grep -oE '[0-9]+ (failed|error)' | awk '{s+=$1} END {print s+0}')
pass=$((pass + p)); fail=$((fail + f))
case "$rc" in
  0) ;;
  5) nok "pytest collected no test" ;;
  *) [ "$f" -gt 0 ] || nok "pytest exited with $rc" ;;
esac
echo "# pytest: $p passed, $f failed ($(( $(date +%s) - t_pytest )) s); the part: $(( $(date +%s) - t0 )) s"
finish
