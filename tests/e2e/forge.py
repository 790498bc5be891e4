#!/usr/bin/env python3
"""Hostile clients for tests/e2e/auth.sh (the attacker has no key).

  forge.py v1 HOST PORT SECONDS
      A blind v1 client (what worked before authentication): open_session,
      power on, impedance, then vpr_stream frames 0.2 m away at ~1 kHz,
      all with valid CRC-32C. Prints what it sent and whether anything came back.
  forge.py forge HOST PORT COUNT [--spoof SRCPORT] [--rate N] [--session ID]
      COUNT v2 vpr_stream frames (84 bytes, version 2, the right layout),
      session ids 1..16 (--session: always ID, the id an eavesdropper reads
      in the session's own frames), increasing sequence numbers ahead of any
      client's, random tags: only the tag can refuse them. With --spoof,
      sent from a raw socket with source 127.0.0.1:SRCPORT: the session's
      own client address (needs root). --rate: datagrams/s.
"""
import os
import socket
import struct
import sys
import time

POLY = 0x82F63B78
TABLE = []
for i in range(256):
    c = i
    for _ in range(8):
        c = (c >> 1) ^ POLY if c & 1 else c >> 1
    TABLE.append(c)


def crc32c(data):
    c = 0xFFFFFFFF
    for b in data:
        c = TABLE[(c ^ b) & 0xFF] ^ (c >> 8)
    return c ^ 0xFFFFFFFF


def header(version, ty, control, session, seq, ts):
    return b"HC" + struct.pack(">BBHHII", version, ty, control, session, seq, ts & 0xFFFFFFFF)


def pose(x):
    return struct.pack(">7f", x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def v1(ty, control, session, seq, payload):
    b = header(1, ty, control, session, seq, int(time.monotonic() * 1e6)) + payload
    return b + struct.pack(">I", crc32c(b))


def blind_v1(host, port, seconds):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.connect((host, port))
    s.setblocking(False)
    sent = got = 0
    seq = 1
    frames = [v1(0x01, 1, 0, seq, struct.pack(">I", 0x41414141))]
    for session in range(1, 9):  # guess the session id the module would grant
        for ty, payload in ((0x0B, struct.pack(">I", 1)), (0x07, struct.pack(">I", 1))):
            seq += 1
            frames.append(v1(ty, 1, session, seq, payload))
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        for f in frames:
            s.send(f)
            sent += 1
        frames = []
        for session in range(1, 9):
            seq += 1
            frames.append(v1(0x0C, 0, session, seq, pose(0.2) + bytes(24)))
        try:
            while True:
                s.recv(256)
                got += 1
        except BlockingIOError:
            pass
        time.sleep(0.008)
    print(f"v1: sent {sent} datagrams, received {got} replies")


def udp_raw(src_port, dst, payload):
    sport, dport = src_port, dst[1]
    udp = struct.pack(">HHHH", sport, dport, 8 + len(payload), 0) + payload
    total = 20 + len(udp)
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, total, 0, 0x4000, 64, socket.IPPROTO_UDP, 0,
                     socket.inet_aton("127.0.0.1"), socket.inet_aton(dst[0]))
    return ip + udp


def forge(host, port, count, spoof, rate, session=None):
    if spoof is not None:
        s = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
    else:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    body = pose(0.2) + bytes(24)
    t0 = time.monotonic()
    sent = 0
    for i in range(count):
        sid = session if session is not None else 1 + i % 16
        f = header(2, 0x0C, 0, sid, 1_000_000 + i, i) + body + os.urandom(16)
        if spoof is not None:
            s.sendto(udp_raw(spoof, (host, port), f), (host, 0))
        else:
            s.sendto(f, (host, port))
        sent += 1
        if rate and i % 100 == 99:
            ahead = sent / rate - (time.monotonic() - t0)
            if ahead > 0:
                time.sleep(ahead)
    dt = time.monotonic() - t0
    print(f"forged: sent {sent} v2 frames{' spoofed from port %d' % spoof if spoof is not None else ''}"
          f"{' with session id %d' % session if session is not None else ''} in {dt:.1f} s")


def main(a):
    if len(a) >= 4 and a[0] == "v1":
        blind_v1(a[1], int(a[2]), float(a[3]))
    elif len(a) >= 4 and a[0] == "forge":
        spoof = int(a[a.index("--spoof") + 1]) if "--spoof" in a else None
        rate = int(a[a.index("--rate") + 1]) if "--rate" in a else 0
        session = int(a[a.index("--session") + 1]) if "--session" in a else None
        forge(a[1], int(a[2]), int(a[3]), spoof, rate, session)
    else:
        print(__doc__, file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main(sys.argv[1:])
