#!/usr/bin/env bash
# The ROS 2 node's figures (Documentation/performance.md, "ROS 2 node"):
# publication rate, DDS-added latency from the controller's answer to a
# Cyclone DDS subscriber (p50/p99), CPU per sample, with the node's release
# build against the fake controller (1 kHz answers), on loopback (host
# native): every answer for 30 s, then a set rate of 500 Hz; the latency
# also at a ros2-client subscriber (examples/latency_probe.rs). The checks of
# tests/ros2/run.sh run too.
#   scripts/bench-ros2.sh [SECONDS]
set -uo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
. "$HERE/lib.sh"
seconds=${1:-30}
rc=0
for args in "" "--rate 500"; do
  echo "## node options: ${args:-(every answer)}"
  min_rate=500; [ -n "$args" ] && min_rate=475
  HAP_ROS2_PROFILE=release HAP_ROS2_SECONDS=$seconds HAP_ROS2_NODE_ARGS="$args" HAP_ROS2_MIN_RATE=$min_rate HAP_ROS2_PROBE=1 \
    bash "$HAP_ROOT/tests/ros2/run.sh" --target fake --results "$HAP_ROOT/build/bench-ros2${args:+-rate}" \
    | grep -E '^# FIGURE|^ros2-|^not ok' || rc=1
done
exit $rc
