#!/usr/bin/env python3
"""Checks the samples a DDS peer received from hapticctrl-ros2 (peer.py
--samples) against what the controller answered, and prints key: value lines.

  check.py SAMPLES fake CX,CY,CZ AX,AY,AZ FIRST_TARGET_NS TX,TY,TZ STIFFNESS DAMPING FREQ
      The fake controller (virtuose_api::fake_peer): the handle at
      c + a*sin(phase) (one phase for all axes, identity orientation); its
      coupling wrench k*(handle - set-point) + d*(handle speed - 0), zero
      before the first set-point arrived.
  check.py SAMPLES module FIRST_TARGET_NS TX,TY,TZ
      The module: poses are rotations (unit quaternions); after the target
      arrived the coupling pulls the handle toward it (the wrench on the
      virtual object points from the target to the handle).
"""
import math
import sys


def triple(s):
    v = [float(x) for x in s.split(",")]
    assert len(v) == 3
    return v


def load(path):
    rows = []
    for line in open(path):
        f = line.split()
        rows.append((int(f[0]), [float(x) for x in f[1:]]))
    return rows


def main():
    rows = load(sys.argv[1])
    mode = sys.argv[2]
    print(f"samples: {len(rows)}")
    qn = max((abs(math.sqrt(sum(v[3 + i] ** 2 for i in range(4))) - 1) for _, v in rows), default=1)
    print(f"max_quaternion_norm_error: {qn:.3e}")
    if mode == "fake":
        c, a = triple(sys.argv[3]), triple(sys.argv[4])
        first = int(sys.argv[5])
        tgt = triple(sys.argv[6])
        k, d, freq = float(sys.argv[7]), float(sys.argv[8]), float(sys.argv[9])
        moving = [i for i in range(3) if a[i] != 0]
        phase_err = still_err = rot_err = over = 0.0
        for _, v in rows:
            s = [(v[i] - c[i]) / a[i] for i in moving]
            phase_err = max(phase_err, max(s) - min(s))
            over = max(over, max(abs(x) for x in s) - 1)
            still_err = max([still_err] + [abs(v[i] - c[i]) for i in range(3) if a[i] == 0])
            rot_err = max(rot_err, abs(v[3]), abs(v[4]), abs(v[5]), abs(v[6] - 1))
        print(f"max_phase_mismatch: {phase_err:.3e}")
        print(f"max_beyond_amplitude: {over:.3e}")
        print(f"max_still_axis_error_m: {still_err:.3e}")
        print(f"max_orientation_error: {rot_err:.3e}")
        # The handle speed is bounded by a*2*pi*f: the damper adds at most d times it.
        vmax = [abs(x) * 2 * math.pi * freq for x in a]
        before = [v for st, v in rows if st < first]
        after = [v for st, v in rows if st > first + 200_000_000]
        print(f"samples_before_target: {len(before)}")
        print(f"samples_with_target: {len(after)}")
        print(f"max_wrench_before_target_n: {max((max(abs(x) for x in v[7:10]) for v in before), default=0):.3e}")
        spring_err = 0.0
        for v in after:
            for i in range(3):
                spring_err = max(spring_err, abs(v[7 + i] - k * (v[i] - tgt[i])) - d * vmax[i])
        print(f"max_wrench_spring_error_n: {spring_err:.3e}")
        if after:
            print(f"mean_wrench_with_target_n: " + ",".join(
                f"{sum(v[7 + i] for v in after) / len(after):.3f}" for i in range(3)))
    else:
        first = int(sys.argv[3])
        tgt = triple(sys.argv[4])
        after = [v for st, v in rows if st > first + 500_000_000]
        print(f"samples_with_target: {len(after)}")
        # Wrench on the virtual object vs. the handle-to-target offset: the
        # coupling spring pulls them together, so force . (handle - target) > 0.
        pulls = sum(1 for v in after if sum(v[7 + i] * (v[i] - tgt[i]) for i in range(3)) > 0)
        print(f"samples_pulling_toward_target: {pulls}")
        if after:
            d0 = math.dist(after[0][:3], tgt)
            d1 = math.dist(after[-1][:3], tgt)
            print(f"distance_to_target_first_m: {d0:.4f}")
            print(f"distance_to_target_last_m: {d1:.4f}")
            print(f"max_wrench_with_target_n: {max(math.sqrt(sum(v[7 + i] ** 2 for i in range(3))) for v in after):.3f}")


if __name__ == "__main__":
    main()
