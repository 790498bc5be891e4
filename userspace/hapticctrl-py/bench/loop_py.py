"""The Python loop of scripts/bench-python.sh: Session.run_loop at 1 kHz with
the same work as loop_c.c (read the handle's pose and the wrench, stream a
pose and a twist). Prints one line in loop_c's format.

    python loop_py.py ADDRESS SECONDS [PERIOD_US]
"""

import sys

import numpy as np

import hapticctrl as hc


def main() -> int:
    address, seconds = sys.argv[1], float(sys.argv[2])
    period_us = int(sys.argv[3]) if len(sys.argv) > 3 else 1000
    lift = np.array([0, 0, 0.001, 0, 0, 0, 0])
    zero = np.zeros(6)
    sink = [0.0]

    def cb(t: hc.Tick):
        sink[0] += t.force[2]
        return t.position + lift, zero

    with hc.Session(address) as s:
        s.set_time_step(period_us * 1e-6)
        s.set_command_type("virtmech")
        s.attach_vo(0.5, [1e-3] * 3)
        s.set_power_on(True)
        s.wait_answer(2.0)
        st = s.run_loop(cb, period=period_us * 1e-6, cycles=int(seconds * 1e6 / period_us), record=True)
        s.set_power_on(False)
    w = np.sort(st.work_us.astype(np.float64))
    print(
        f"python: cycles={st.cycles} rate_hz={st.rate_hz:.1f} period_mean_us={st.period_mean_us:.1f} "
        f"period_std_us={st.period_std_us:.1f} period_max_us={st.period_max_us:.1f} "
        f"lateness_max_us={st.lateness_max_us:.1f} work_mean_us={st.work_mean_us:.2f} "
        f"work_p50_us={w[len(w) // 2]:.2f} "
        f"work_p99_us={w[int(len(w) * 0.99)]:.2f} work_max_us={st.work_max_us:.1f} overruns={st.overruns}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
