#!/usr/bin/env bash
# The MuJoCo example against the fake controller, in one command: builds
# hapctl and hapticctrl-fake (cargo, release; a no-op once built), makes a
# key with `hapctl keygen` (once: OUT/hap.key), starts hapticctrl-fake with
# it (authenticated, a scripted handle that moves 6 cm up and down, so the
# tool is pushed into MuJoCo's table and lifted off it), runs
# examples/mujoco_table.py against it, stops the fake and prints where the
# plot and the samples are.
#   userspace/hapticctrl-py/examples/mujoco-fake.sh [--duration S] [--out DIR] [--viewer]
#                                                   [-- MUJOCO_TABLE_ARGS...]
# --duration: seconds of the example (default 10); --out: where the key,
# the plot (mujoco_table.png) and the samples (mujoco_table.npz) go
# (default build/mujoco-fake); --viewer: MuJoCo's viewer (needs a display;
# headless otherwise). PYTHON: the interpreter hapticctrl and mujoco are
# installed in (default python3 on PATH: pip install
# 'userspace/hapticctrl-py[mujoco]' there first).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
duration=10; out=$ROOT/build/mujoco-fake; view=--headless; extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --duration) duration=${2:?--duration S}; shift ;;
    --out) out=${2:?--out DIR}; shift ;;
    --viewer) view=--viewer ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,/^set -e/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) echo "mujoco-fake.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
  esac
  shift
done
py=${PYTHON:-python3}
if ! "$py" -c 'import hapticctrl, mujoco' 2>/dev/null; then
  echo "mujoco-fake.sh: $py cannot import hapticctrl and mujoco; install them first:" >&2
  echo "  $py -m pip install '$ROOT/userspace/hapticctrl-py[mujoco]'" >&2
  exit 1
fi

echo "building hapctl and hapticctrl-fake (cargo build --release; the first time takes minutes)"
(cd "$ROOT/userspace" && cargo build --release --quiet -p hapctl -p hapticctrl-py --bin hapctl --bin hapticctrl-fake)
target=${CARGO_TARGET_DIR:-$ROOT/userspace/target}/release
mkdir -p "$out"
key=$out/hap.key
[ -f "$key" ] || "$target/hapctl" keygen "$key"

fifo=$(mktemp -u); mkfifo "$fifo"
"$target/hapticctrl-fake" --key "$key" --center 0,0,0 --amplitude 0,0,0.06 --freq 0.5 \
  < "$fifo" > "$out/fake.txt" 2> "$out/fake.err" &
fake=$!
exec {hold}> "$fifo"
rm -f "$fifo"
stop() { exec {hold}>&- 2>/dev/null || true; wait "$fake" 2>/dev/null || true; }
trap stop EXIT
for _ in $(seq 100); do grep -q '^PORT ' "$out/fake.txt" && break; sleep 0.1; done
port=$(sed -n 's/^PORT //p' "$out/fake.txt")
[ -n "$port" ] || { cat "$out/fake.err" >&2; echo "mujoco-fake.sh: hapticctrl-fake did not start" >&2; exit 1; }
echo "fake controller on 127.0.0.1#$port (key $key); the example for $duration s"
MPLBACKEND=${MPLBACKEND:-Agg} "$py" "$HERE/mujoco_table.py" --address "127.0.0.1#$port" --key "$key" \
  --duration "$duration" --out "$out" "$view" "${extra[@]}"
stop
trap - EXIT
echo "fake controller: $(grep -E '^(handshakes|answers_sent|session_open):' "$out/fake.txt" | tr '\n' ' ')"
echo "samples: $out/mujoco_table.npz"
