#!/usr/bin/env python3
"""Kill a running test client and keep listening on its UDP socket.

    answer_watch.py --pid PID --period-us P [--seconds S] [--csv FILE]

Used by scripts/bench-faults.sh, scenario (a). The client (virtuose_demo)
is killed with SIGKILL mid-session; just before, this script takes a
duplicate of the client's UDP socket (pidfd_open + pidfd_getfd, Linux >= 5.6,
needs ptrace rights over the client: same user or root), so the controller's
answers that keep coming to the dead client's address are still received:
nothing is lost between the kill and the first recv, the socket buffer holds
them. From the `answer` frames (protocol.md: 0x81, 88 bytes; status bits in
hap-core vp.rs) it measures the link watchdog's fade in servo cycles:

  L = the last cycle whose VPr was fresh (status VPR_EXTRAPOLATED 0x200 clear),
      i.e. the cycle that used the last frame the controller received;
  F = the first cycle after L with LINK_FADING (0x100) set;
  Z = the first cycle after L whose coupling wrench is exactly 0 with
      LINK_FADING set; every later answer must have a zero wrench too.

The VPr age is counted in whole cycles (cycles since PROTO_IN decoded the
frame x period) and VPR_EXTRAPOLATED means "older than one period", so the
last frame's age is exactly one period at L (it is 0 or 1 there, and more
than 1 at L + 1): the frame was received Z - L + 1 cycles before the zero
wrench (`fade_to_zero_after_last_frame_*`).

Prints `key: value` lines (cycles, guest ms = cycles x period, host seconds
from the kill to the receipt of Z). Exit status 1 if the wrench never reached
0 or came back, 2 on usage or system errors.
"""

import argparse
import ctypes
import os
import signal
import socket
import struct
import sys
import time

SYS_PIDFD_OPEN = 434
SYS_PIDFD_GETFD = 438
ANSWER = 0x81
ANSWER_LEN = 88
LINK_FADING = 0x100
VPR_EXTRAPOLATED = 0x200
COUPLED = 0x80


def udp_inodes():
    """inode -> (local port, remote port) of this netns' UDP sockets."""
    out = {}
    for path in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(path) as f:
                next(f)
                for line in f:
                    w = line.split()
                    lport = int(w[1].rsplit(":", 1)[1], 16)
                    rport = int(w[2].rsplit(":", 1)[1], 16)
                    out[int(w[9])] = (lport, rport)
        except FileNotFoundError:
            pass
    return out


def client_socket_fd(pid, server_port):
    """The fd number, in `pid`, of its UDP socket (the one talking to
    server_port if several)."""
    udp = udp_inodes()
    cands = []
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            ino = int(link[8:-1])
            if ino in udp:
                cands.append((udp[ino][1] == server_port, int(fd), udp[ino][0]))
    if not cands:
        raise SystemExit(f"answer_watch: no UDP socket in pid {pid}")
    cands.sort(reverse=True)
    return cands[0][1], cands[0][2]


def steal_fd(pid, fd):
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    pidfd = libc.syscall(SYS_PIDFD_OPEN, pid, 0)
    if pidfd < 0:
        raise OSError(ctypes.get_errno(), "pidfd_open")
    nfd = libc.syscall(SYS_PIDFD_GETFD, pidfd, fd, 0)
    if nfd < 0:
        raise OSError(ctypes.get_errno(), "pidfd_getfd")
    os.close(pidfd)
    return nfd


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pid", type=int, required=True)
    ap.add_argument("--period-us", type=int, required=True)
    ap.add_argument("--server-port", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--csv")
    a = ap.parse_args()
    if a.period_us <= 0 or a.seconds <= 0:
        ap.error("--period-us and --seconds must be positive")

    fd, lport = client_socket_fd(a.pid, a.server_port)
    sock = socket.socket(fileno=steal_fd(a.pid, fd))
    sock.settimeout(0.2)
    os.kill(a.pid, signal.SIGKILL)
    t_kill = time.monotonic()
    print(f"client_pid: {a.pid}")
    print(f"client_udp_port: {lport}")

    rows = {}  # cycle -> (t_recv, status, vpr_seq, |force|, |torque|)
    while time.monotonic() - t_kill < a.seconds:
        try:
            data = sock.recv(2048)
        except socket.timeout:
            continue
        t = time.monotonic() - t_kill
        if len(data) != ANSWER_LEN or data[3] != ANSWER:
            continue
        v = struct.unpack_from(">7f6fIIII", data, 16)
        force = sum(x * x for x in v[7:10]) ** 0.5
        torque = sum(x * x for x in v[10:13]) ** 0.5
        status, _alarms, cycle, vpr_seq = v[13:17]
        rows.setdefault(cycle, (t, status, vpr_seq, force, torque))
    sock.close()
    if a.csv:
        with open(a.csv, "w") as f:
            f.write("cycle,t_after_kill_s,status,vpr_seq,force_n,torque_nm\n")
            for c in sorted(rows):
                t, st, seq, fo, to = rows[c]
                f.write(f"{c},{t:.4f},{st:#x},{seq},{fo:.6f},{to:.6f}\n")
    cycles = sorted(rows)
    print(f"answers_after_kill: {len(cycles)}")
    if not cycles:
        print("error: no answer received after the kill")
        return 1
    fresh = [c for c in cycles if not rows[c][1] & VPR_EXTRAPOLATED]
    if fresh:
        last_fresh = fresh[-1]
        exact = "yes"
    else:
        # Every buffered answer already had an extrapolated VPr: the last
        # fresh cycle is before the first one seen (a bound, not a value).
        last_fresh = cycles[0] - 1
        exact = "no (upper bound: before the first answer seen)"
    after = [c for c in cycles if c > last_fresh]
    fading = [c for c in after if rows[c][1] & LINK_FADING]
    zero = [c for c in after if rows[c][1] & LINK_FADING and rows[c][3] == 0.0 and rows[c][4] == 0.0]
    p_ms = a.period_us / 1000.0
    print(f"last_fresh_vpr_cycle: {last_fresh}")
    print(f"last_fresh_cycle_observed: {exact}")
    print(f"last_vpr_seq: {rows[cycles[-1]][2]}")
    before = [rows[c][3] for c in after if not rows[c][1] & LINK_FADING]
    print(f"force_before_fade_max_n: {max(before) if before else 0.0:.4f}")
    if fading:
        f0 = fading[0]
        print(f"fade_start_cycles: {f0 - last_fresh}")
        print(f"fade_start_guest_ms: {(f0 - last_fresh) * p_ms:.1f}")
        ramp = [f"{rows[c][3]:.3f}" for c in after if f0 <= c <= (zero[0] if zero else f0)]
        print(f"fade_ramp_force_n: {' '.join(ramp)}")
    if not zero:
        print("error: the coupling wrench never reached 0")
        return 1
    z = zero[0]
    back = [c for c in cycles if c > z and (rows[c][3] != 0.0 or rows[c][4] != 0.0)]
    print(f"zero_wrench_cycle: {z}")
    print(f"fade_to_zero_cycles: {z - last_fresh}")
    print(f"fade_to_zero_guest_ms: {(z - last_fresh) * p_ms:.1f}")
    if exact == "yes":
        print(f"fade_to_zero_after_last_frame_cycles: {z - last_fresh + 1}")
        print(f"fade_to_zero_after_last_frame_guest_ms: {(z - last_fresh + 1) * p_ms:.1f}")
    print(f"zero_wrench_host_s_after_kill: {rows[z][0]:.3f}")
    print(f"answers_zero_after: {len([c for c in cycles if c >= z]) - len(back)}")
    if back:
        print(f"error: the wrench came back at cycle {back[0]}")
        return 1
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except OSError as e:
        print(f"answer_watch: {e}", file=sys.stderr)
        sys.exit(2)
