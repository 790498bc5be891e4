#!/usr/bin/env bash
# The Python loop next to the C client, in one run against one fake
# controller (hapticctrl-fake, authenticated, on the host): the achieved
# rate and jitter of Session.run_loop at 1 kHz and of the same loop in C on
# libvirtuose_api (userspace/hapticctrl-py/bench/loop_c.c: absolute
# clock_nanosleep deadlines), and the work time from the wake-up to the
# set-point sent (the Python callback's extra latency over C). The two
# loops run one after the other, ROUNDS times alternately. Mode: host
# native (this machine's scheduler, SCHED_OTHER). Figures printed, nothing
# asserted.
#   scripts/bench-python.sh [--seconds S] [--rounds N] [--period-us N] [--results DIR]
set -uo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
. "$HERE/python-venv.sh"
seconds=10; rounds=2; period_us=1000; results="$HAP_ROOT/build/bench-python"
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=${2:-}; shift ;;
    --rounds) rounds=${2:-}; shift ;;
    --period-us) period_us=${2:-}; shift ;;
    --results) results=${2:-}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
mkdir -p "$results"
hap_python_venv "$results" || die "Python virtual environment"
hap_python_wheel "$results" || die "wheel"
(cd "$HAP_ROOT/userspace" && cargo build --release --quiet -p virtuose_api --lib && cargo build --release --quiet -p hapticctrl-py --bin hapticctrl-fake) \
  || die "cargo build"
bench="$HAP_ROOT/userspace/hapticctrl-py/bench"
cc -O2 -I "$HAP_ROOT/include" "$bench/loop_c.c" "$CARGO_TARGET_DIR/release/libvirtuose_api.a" -lpthread -ldl -lm \
  -o "$results/loop_c" || die "cc loop_c.c"
key="$results/hap.key"
[ -f "$key" ] || (umask 077 && "$py" -c 'import secrets; print(secrets.token_hex(32))' > "$key")
fifo="$results/fake.in"; rm -f "$fifo"; mkfifo "$fifo"
"$CARGO_TARGET_DIR/release/hapticctrl-fake" --key "$key" --period-us "$period_us" < "$fifo" > "$results/fake.txt" 2>&1 &
fpid=$!
exec {hold}> "$fifo"
for _ in $(seq 100); do grep -q '^PORT ' "$results/fake.txt" && break; sleep 0.1; done
port=$(sed -n 's/^PORT //p' "$results/fake.txt")
[[ "$port" =~ ^[0-9]+$ ]] || die "hapticctrl-fake did not start"
addr="127.0.0.1#$port?key=$key"
report="$results/report.txt"
{
  echo "# bench-python: $(date -u +%FT%TZ), mode: host native ($(uname -r), $(nproc) CPUs, SCHED_OTHER), period $period_us us, $seconds s per loop, $rounds rounds"
  echo "# $("$py" --version), hapticctrl $("$py" -c 'import hapticctrl; print(hapticctrl.__version__)'), $(cc --version | head -1)"
  echo "# load average: $(cut -d' ' -f1-3 /proc/loadavg)"
} | tee "$report"
for r in $(seq "$rounds"); do
  "$results/loop_c" "$addr" "$seconds" "$period_us" | sed "s/^/round $r /" | tee -a "$report"
  "$py" "$bench/loop_py.py" "$addr" "$seconds" "$period_us" | sed "s/^/round $r /" | tee -a "$report"
done
exec {hold}>&-
wait "$fpid"
echo "# load average after: $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$report"
echo "report: $report"
