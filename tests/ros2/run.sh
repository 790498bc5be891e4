#!/usr/bin/env bash
# hapticctrl-ros2 against an independent DDS implementation: Eclipse Cyclone
# DDS's Python binding (PyPI `cyclonedds`, in a venv under the cache; no ROS
# installation) as a ROS 2 peer with ROS 2's topic names (rt/hapticctrl/...)
# and the standard message types (tests/ros2/peer.py). Loopback only, with
# unicast discovery (the loopback has no MULTICAST flag): Cyclone restricted
# to 127.0.0.1 with 127.0.0.1 as its peer, the node's RustDDS participant
# announcing 127.0.0.1 only. The peer subscribes to the node's pose, joint
# states, wrench and status and publishes target poses; the checks compare
# the samples with the controller's answers, the rates, and that the
# set-points reached the controller and moved the coupling target.
#   tests/ros2/run.sh [--target fake|qemu] [--self-built-kernel] [--port N] [--domain N] [--results DIR]
# fake: the fake controller (virtuose_api::fake_peer, 1 kHz answers) on the
# host; the node's debug build (what cargo test builds), 12 s of traffic.
# qemu: the module in QEMU (Debian's stock rt-amd64 kernel, make STOCK=1;
# --self-built-kernel: the project's test kernel) and
# the authenticated bridge, the node on the host over UDP 127.0.0.1:PORT
# (default 47600) -> guest:5000 (a few minutes, most of it the guest's boot);
# the emulated guest answers at its own pace (TCG), so the rate checked there
# is the node's answer rate, not 500 Hz.
# Environment (scripts/bench-ros2.sh): HAP_ROS2_PROFILE=release for the
# node's release build, HAP_ROS2_SECONDS (fake: 12) for a longer run,
# HAP_ROS2_NODE_ARGS for more node options (e.g. "--rate 500"),
# HAP_ROS2_MIN_RATE for the rate the peer must see (fake: 500 Hz),
# HAP_ROS2_PROBE=1 for a ros2-client subscriber measuring the latency too.
# Prints every check, then "ros2-TARGET: N passed, N failed".
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
. "$ROOT/scripts/lib.sh"
target=fake; results=""; kflag=--stock; makeflag=STOCK=1; port=${HAP_ROS2_PORT:-47600}; domain=${HAP_ROS2_DOMAIN:-42}
while [ $# -gt 0 ]; do
  case "$1" in
    --target) target=${2:-}; shift ;;
    --self-built-kernel) kflag=""; makeflag="" ;;
    --port) port=${2:-}; shift ;;
    --domain) domain=${2:-}; shift ;;
    --results) results=${2:-}; shift ;;
    -h|--help) hap_usage; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
  shift
done
case "$target" in fake|qemu) ;; *) die "--target fake or qemu, got '$target'" ;; esac
[[ "$port" =~ ^[0-9]+$ ]] && [ "$port" -ge 1024 ] && [ "$port" -le 65535 ] || die "--port $port: 1024..65535"
[[ "$domain" =~ ^[0-9]+$ ]] && [ "$domain" -le 232 ] || die "--domain $domain: 0..232"
results=${results:-$ROOT/build/ros2-$target}
mkdir -p "$results"; rm -rf "${results:?}"/*
t_start=$(date +%s)

pass=0; fail=0
ok() { pass=$((pass + 1)); echo "ok - $*"; }
nok() { fail=$((fail + 1)); echo "not ok - $*"; }
check_num() { # desc value op limit
  if awk -v v="$2" -v l="$4" "BEGIN { exit !(v $3 l) }"; then ok "$1 ($2 $3 $4)"; else nok "$1 (got '$2', want $3 $4)"; fi
}
finish() { echo "# FIGURE ros2-$target wall time: $(( $(date +%s) - t_start )) s"; echo "ros2-$target: $pass passed, $fail failed"; [ "$fail" = 0 ]; exit $?; }

# ---- Cyclone DDS's Python binding, pinned, in a venv (cached)
CYCLONEDDS_VERSION=11.0.1
venv="$HAP_CACHE/ros2-venv"
py="$venv/bin/python"
if ! "$py" -c "import cyclonedds, importlib.metadata as m; assert m.version('cyclonedds') == '$CYCLONEDDS_VERSION'" 2>/dev/null; then
  log "installing cyclonedds $CYCLONEDDS_VERSION (PyPI) into $venv"
  { python3 -m venv "$venv" && "$venv/bin/pip" install -q "cyclonedds==$CYCLONEDDS_VERSION"; } > "$results/pip.log" 2>&1 \
    || { tail -5 "$results/pip.log"; nok "install cyclonedds $CYCLONEDDS_VERSION from PyPI"; finish; }
fi
ok "Cyclone DDS Python binding $("$py" -c 'import importlib.metadata as m; print(m.version("cyclonedds"))') (no ROS installation: $(command -v ros2 >/dev/null && echo "ros2 found!" || echo "no ros2 command"))"

# Loopback only, unicast discovery: Cyclone on 127.0.0.1, its SPDP sent to
# 127.0.0.1's well-known ports (participant indices 0..20).
cat > "$results/cyclonedds.xml" <<'XML'
<CycloneDDS><Domain id="any">
  <General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces><AllowMulticast>false</AllowMulticast></General>
  <Discovery><Peers><Peer address="127.0.0.1"/></Peers><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>20</MaxAutoParticipantIndex></Discovery>
</Domain></CycloneDDS>
XML
export CYCLONEDDS_URI="file://$results/cyclonedds.xml"

# ---- the node, the fake controller and the joint check (debug builds: the
# ones cargo test --workspace compiles)
t_build=$(date +%s)
profile=${HAP_ROS2_PROFILE:-debug}
case "$profile" in debug) pflag="" ;; release) pflag=--release ;; *) die "HAP_ROS2_PROFILE=$profile: debug or release" ;; esac
seconds=${HAP_ROS2_SECONDS:-12}
[[ "$seconds" =~ ^[0-9]+$ ]] && [ "$seconds" -ge 8 ] || die "HAP_ROS2_SECONDS=$seconds: whole seconds >= 8"
read -r -a node_args <<< "${HAP_ROS2_NODE_ARGS:-}"
(cd "$ROOT/userspace" && cargo build --quiet $pflag -p hapticctrl-ros2 --bins --examples -p virtuose_api --example fake_controller) \
  > "$results/build.log" 2>&1 || { tail -20 "$results/build.log"; nok "build hapticctrl-ros2"; finish; }
echo "# FIGURE build ($profile, incremental): $(( $(date +%s) - t_build )) s"
bin="$ROOT/userspace/target/$profile"
node="$bin/hapticctrl-ros2"

fv() { sed -n "s/^$1: //p" "$2" | head -1; }
# The peer's and the node's figures, and the checks common to both targets.
# common_checks MIN_RATE
common_checks() {
  local min_rate=$1 P="$results/peer.txt" N="$results/node.txt"
  sed 's/^/# node: /' "$N"
  grep -v '^status\.' "$P" | sed 's/^/# peer: /'
  check_num "the node published without an error" "$(fv publish_errors "$N")" '==' 0
  check_num "no set-point rejected by the node" "$(fv rejected "$N")" '==' 0
  check_num "Cyclone received the pose (geometry_msgs/PoseStamped on rt/hapticctrl/pose)" "$(fv pose.samples "$P")" '>=' 100
  check_num "Cyclone received the joint states (sensor_msgs/JointState)" "$(fv joint_states.samples "$P")" '>=' 100
  check_num "Cyclone received the coupling wrench (geometry_msgs/WrenchStamped)" "$(fv wrench.samples "$P")" '>=' 100
  check_num "pose rate at the peer (Hz)" "$(fv pose.rate_hz "$P")" '>=' "$min_rate"
  check_num "joint-state rate at the peer (Hz)" "$(fv joint_states.rate_hz "$P")" '>=' "$min_rate"
  check_num "pose stamps strictly increasing" "$(fv pose.stamps_increasing "$P")" '==' 1
  [ "$(fv pose.frame_id "$P")" = hapticctrl_base ] && ok "pose frame_id hapticctrl_base" || nok "pose frame_id '$(fv pose.frame_id "$P")'"
  [ "$(fv joint_states.names "$P")" = "hapticctrl_joint1,hapticctrl_joint2,hapticctrl_joint3,hapticctrl_joint4,hapticctrl_joint5,hapticctrl_joint6" ] \
    && ok "joint names hapticctrl_joint1..6" || nok "joint names '$(fv joint_states.names "$P")'"
  check_num "Cyclone received the status (diagnostic_msgs/DiagnosticStatus, reliable)" "$(fv status.samples "$P")" '>=' 1
  [ "$(fv status.power_on "$P")" = true ] && ok "status: power on (the node's --power-on)" || nok "status power_on '$(fv status.power_on "$P")'"
  [ "$(fv status.fail_safe "$P")" = false ] && ok "status: no fail-safe" || nok "status fail_safe '$(fv status.fail_safe "$P")'"
  check_num "targets published by Cyclone (geometry_msgs/PoseStamped on rt/hapticctrl/target_pose)" "$(fv targets_sent "$P")" '>=' 50
  check_num "targets the node received" "$(fv targets "$N")" '>=' 25
  check_num "set-points the node streamed to the controller" "$(fv setpoints_streamed "$N")" '>=' 25
  "$bin/examples/joint_check" "$results/samples.txt" > "$results/joints.txt" 2>&1
  sed 's/^/# joints: /' "$results/joints.txt"
  check_num "joint states matched to poses by stamp" "$(fv joint_samples "$results/joints.txt")" '>=' 100
  check_num "forward kinematics of the joint states = the pose (m)" "$(fv max_position_error_m "$results/joints.txt")" '<' 1e-5
  check_num "forward kinematics of the joint states = the orientation" "$(fv max_orientation_error "$results/joints.txt")" '<' 1e-5
  echo "# FIGURE DDS-added latency, answer -> Cyclone subscriber ($target): pose p50 $(fv pose.latency_us_p50 "$P") us, p99 $(fv pose.latency_us_p99 "$P") us; joint_states p50 $(fv joint_states.latency_us_p50 "$P") us, p99 $(fv joint_states.latency_us_p99 "$P") us"
  echo "# FIGURE node ($target, $profile build, ${node_args[*]:-every answer}): $(fv answer_rate_hz "$N") answers/s, CPU $(fv cpu_us_per_answer "$N") us per answer, $(awk -v c="$(fv cpu_s "$N")" -v n="$(fv published "$N")" 'BEGIN { printf "%.1f", (n > 0 ? c * 1e6 / n : 0) }') us per sample ($(fv published "$N") samples on 4 streaming topics, $(fv cpu_s "$N") s CPU in $(fv wall_s "$N") s)"
  echo "# FIGURE rates ($target): node $(fv answer_rate_hz "$N") answers/s over its run, peer pose $(fv pose.rate_hz "$P") Hz, joint_states $(fv joint_states.rate_hz "$P") Hz over the samples' stamps; load average $(cut -d' ' -f1-3 /proc/loadavg)"
}

if [ "$target" = fake ]; then
  fc="$bin/examples/fake_controller"
  center=0.45,0.05,0.25; amplitude=0.05,0.02,0; tgt=0.46,0.05,0.26; freq=0.5
  mkfifo "$results/fake.in"
  "$fc" --duration $((seconds + 60)) --period-us 1000 --center "$center" --amplitude "$amplitude" \
    < "$results/fake.in" > "$results/fake.txt" 2> "$results/fake.err" &
  fpid=$!
  exec {hold}> "$results/fake.in"
  for _ in $(seq 100); do grep -q '^PORT ' "$results/fake.txt" && break; sleep 0.1; done
  fport=$(sed -n 's/^PORT //p' "$results/fake.txt")
  [[ "$fport" =~ ^[0-9]+$ ]] || { exec {hold}>&-; nok "fake controller did not start: $(cat "$results/fake.err")"; finish; }
  echo "# fake controller on 127.0.0.1:$fport (1 kHz answers)"
  "$node" --server "127.0.0.1#$fport" --domain-id "$domain" --dds-address 127.0.0.1 --duration "$seconds" \
    --power-on --command-type virtmech "${node_args[@]}" > "$results/node.txt" 2> "$results/node.err" &
  npid=$!
  probe_pid=""
  if [ "${HAP_ROS2_PROBE:-0}" = 1 ]; then
    "$bin/examples/latency_probe" "$domain" /hapticctrl $((seconds - 3)) > "$results/probe.txt" 2>&1 &
    probe_pid=$!
  fi
  timeout $((seconds + 60)) "$py" "$ROOT/tests/ros2/peer.py" --domain "$domain" --duration $((seconds - 3)) --target "$tgt" --target-after 4 \
    --samples "$results/samples.txt" > "$results/peer.txt" 2> "$results/peer.err"
  prc=$?
  wait "$npid"; nrc=$?
  if [ -n "$probe_pid" ]; then
    wait "$probe_pid"
    echo "# FIGURE DDS-added latency, answer -> ros2-client subscriber (fake, $(fv probe.samples "$results/probe.txt") samples): pose p50 $(fv probe.latency_us_p50 "$results/probe.txt") us, p99 $(fv probe.latency_us_p99 "$results/probe.txt") us, max $(fv probe.latency_us_max "$results/probe.txt") us"
  fi
  exec {hold}>&-
  wait "$fpid"
  sed 's/^/# node: /' "$results/node.err"
  [ "$prc" = 0 ] && ok "the Cyclone peer ran" || { tail -5 "$results/peer.err"; nok "the Cyclone peer exited with $prc"; }
  [ "$nrc" = 0 ] && ok "the node ran its $seconds s and exited with 0" || nok "the node exited with $nrc"
  common_checks "${HAP_ROS2_MIN_RATE:-500}"
  sed 's/^/# fake: /' "$results/fake.txt"
  check_num "the node opened one session" "$(fv frames.open_session "$results/fake.txt")" '==' 1
  check_num "and closed it" "$(fv frames.close_session "$results/fake.txt")" '==' 1
  check_num "command type virtmech (2)" "$(fv command_type "$results/fake.txt")" '==' 2
  # Before the targets, nothing streams: the node keeps the session alive
  # with its time step (a bridge closes a session silent for 3 s).
  check_num "keep-alive requests while no set-point streamed" "$(fv keepalives "$results/node.txt")" '>=' 2
  check_num "the controller got them (time step requests: the first one and the keep-alives)" "$(fv frames.set_time_step "$results/fake.txt")" '==' "$(( $(fv keepalives "$results/node.txt") + 1 ))"
  streamed=$(fv setpoints_streamed "$results/node.txt")
  check_num "the controller received the set-points (VPr frames; UDP on loopback may drop a few)" "$(fv frames.vpr_stream "$results/fake.txt")" '>=' "$(awk -v n="${streamed:-0}" 'BEGIN { printf "%d", 0.99 * n }')"
  check_num "no more VPr frames than the node streamed" "$(fv frames.vpr_stream "$results/fake.txt")" '<=' "${streamed:-0}"
  last_vo=$(fv last_vo_pose "$results/fake.txt")
  d_vo=$(awk -v a="$last_vo" -v b="$tgt" 'BEGIN { split(a, x, ","); split(b, y, ","); d = 0; for (i = 1; i <= 3; i++) d += (x[i] - y[i]) ^ 2; printf "%.3e", sqrt(d) }')
  check_num "the coupling target is the target published over DDS (m)" "$d_vo" '<' 1e-6
  first=$(fv first_target_ns "$results/peer.txt")
  "$py" "$ROOT/tests/ros2/check.py" "$results/samples.txt" fake "$center" "$amplitude" "${first:-0}" "$tgt" 300 4 "$freq" > "$results/check.txt" 2>&1
  sed 's/^/# content: /' "$results/check.txt"
  cv() { fv "$1" "$results/check.txt"; }
  check_num "pose: every sample on the controller's trajectory (one phase for x and y)" "$(cv max_phase_mismatch)" '<' 1e-5
  check_num "pose: within the trajectory's amplitude" "$(cv max_beyond_amplitude)" '<' 1e-5
  check_num "pose: z where the controller holds it (m)" "$(cv max_still_axis_error_m)" '<' 1e-6
  check_num "pose: the controller's orientation (identity)" "$(cv max_orientation_error)" '<' 1e-6
  check_num "wrench samples before the first target" "$(cv samples_before_target)" '>=' 100
  check_num "wrench before any set-point: zero (N)" "$(cv max_wrench_before_target_n)" '==' 0
  check_num "wrench samples with the target" "$(cv samples_with_target)" '>=' 100
  check_num "wrench with the target = the controller's spring to it, 300 N/m (N beyond the damper's bound)" "$(cv max_wrench_spring_error_n)" '<' 1e-3
  finish
fi

# ---- QEMU: the module and proto_interface in the guest, UDP from the host
t_build=$(date +%s)
(cd "$ROOT" && nice -n 10 make -s $makeflag) > "$results/make.log" 2>&1 || { tail -5 "$results/make.log"; nok "module build (make $makeflag)"; finish; }
nice -n 10 bash "$ROOT/scripts/build-userspace-static.sh" > "$results/static.log" 2>&1 \
  || { tail -5 "$results/static.log"; nok "static userspace build"; finish; }
key=$(hap_keyfile "$ROOT/build/hap-test.key")
t_guest=$(date +%s)
period_us=1000
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background $kflag --icount \
  --udp "$port:5000" --key "$key" --log "$results/guest.log" "$ROOT/tests/guest/serve.sh" "$period_us" 300)
stop_guest() { kill $(pgrep -P "$qpid" 2>/dev/null) "$qpid" 2>/dev/null; }
trap stop_guest EXIT
until_s=$(( $(date +%s) + 600 ))
while [ "$(date +%s)" -lt "$until_s" ]; do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.2; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; nok "the guest did not get ready"; finish; }
echo "# FIGURE guest ready after $(( $(date +%s) - t_guest )) s (boot, insmod, bridge)"
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# guest ready (servo period ${period_us} us, TCG icount); UDP 127.0.0.1:$port -> guest:5000, authenticated"
"$node" --server "127.0.0.1#$port" --key "$key" --domain-id "$domain" --dds-address 127.0.0.1 --duration 40 \
  --power-on --command-type impedance > "$results/node.txt" 2> "$results/node.err" &
npid=$!
timeout 90 "$py" "$ROOT/tests/ros2/peer.py" --domain "$domain" --duration 36 --target-offset 0,0,0.01 --target-after 12 \
  --target-rate 200 --samples "$results/samples.txt" > "$results/peer.txt" 2> "$results/peer.err"
prc=$?
wait "$npid"; nrc=$?
sed 's/^/# node: /' "$results/node.err"
until_s=$(( $(date +%s) + 600 ))
while [ "$(date +%s)" -lt "$until_s" ]; do kill -0 "$qpid" 2>/dev/null || break; sleep 0.2; done
stop_guest
trap - EXIT
echo "# FIGURE wall time: builds $((t_guest - t_build)) s, guest (boot, run, log dump) $(( $(date +%s) - t_guest )) s"
[ "$prc" = 0 ] && ok "the Cyclone peer ran" || { tail -5 "$results/peer.err"; nok "the Cyclone peer exited with $prc"; }
[ "$nrc" = 0 ] && ok "the node ran its 40 s and exited with 0" || nok "the node exited with $nrc"
# The guest answers at its emulated pace: the peer must see the node's
# answer rate (every answer published), whatever it is.
nrate=$(fv answer_rate_hz "$results/node.txt")
common_checks "$(awk -v r="${nrate:-0}" 'BEGIN { printf "%.1f", 0.8 * r }')"
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt"
between HAP-PROTO > "$results/proto_interface.txt"
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }
echo "# module: cycles $(gv hap_stats.txt cycles), misses $(gv hap_stats.txt misses), vpr frames $(gv hap_stats.txt vpr_frames), answers sent $(gv hap_stats.txt answers_sent)"
check_num "module: a session opened" "$(gv hap_stats.txt sessions_opened)" '>=' 1
check_num "module: the session is closed at the end" "$(gv hap_stats.txt session)" '==' 0
check_num "module: the set-points arrived (VPr frames)" "$(gv hap_stats.txt vpr_frames)" '>=' 25
check_num "module: no more set-points than the node streamed" "$(gv hap_stats.txt vpr_frames)" '<=' "$(fv setpoints_streamed "$results/node.txt")"
check_num "module: nothing malformed reached it" "$(gv hap_stats.txt frames_rejected)" '==' 0
check_num "module: no fail-safe" "$(gv hap_stats.txt fail_safe)" '==' 0
check_num "bridge: authenticated (not --insecure)" "$(gv proto_interface.txt insecure)" '==' 0
check_num "bridge: no frame failed its tag" "$(gv proto_interface.txt rejected_bad_tag)" '==' 0
check_num "bridge: the session did not expire (the node's keep-alives while it streams nothing)" "$(gv proto_interface.txt sessions_expired)" '==' 0
check_num "bridge: the node closed its session" "$(gv proto_interface.txt sessions_closed)" '==' 1
first=$(fv first_target_ns "$results/peer.txt")
tgt=$(fv target "$results/peer.txt")
"$py" "$ROOT/tests/ros2/check.py" "$results/samples.txt" module "${first:-0}" "${tgt:-0,0,0}" > "$results/check.txt" 2>&1
sed 's/^/# content: /' "$results/check.txt"
cv() { fv "$1" "$results/check.txt"; }
check_num "pose: unit quaternions" "$(cv max_quaternion_norm_error)" '<' 1e-5
check_num "samples with the target (1 cm above the handle)" "$(cv samples_with_target)" '>=' 20
check_num "the coupling wrench pulls the handle toward the target published over DDS (samples)" "$(cv samples_pulling_toward_target)" '>=' "$(awk -v n="$(cv samples_with_target)" 'BEGIN { printf "%d", 0.9 * n }')"
check_num "the coupling wrench with the target (N)" "$(cv max_wrench_with_target_n)" '>' 0.1
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed (a client opened and closed a session; clean stop)" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
finish
