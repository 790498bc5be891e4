#!/usr/bin/env python3
"""Send N hostile datagrams to the bridge from a fresh source port: random
bytes of random length (0..200, so oversized and undersized too), frames with
a valid header and bad CRC, and truncated copies. Bounded in count and time;
loopback only."""
import os, random, socket, struct, sys, time

host, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
assert host.startswith("127."), "loopback only"
delay = float(sys.argv[4]) if len(sys.argv) > 4 else 0.0
time.sleep(delay)
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
rng = random.Random(1234)
t0 = time.time()
for i in range(n):
    kind = i % 4
    if kind == 0:
        b = os.urandom(rng.randrange(0, 200))
    elif kind == 1:
        b = b"HC\x01\x0c" + os.urandom(68)          # vpr_stream length, bad CRC
    elif kind == 2:
        b = b"HC\x01\x01" + os.urandom(rng.randrange(0, 30))  # wrong length
    else:
        b = os.urandom(90)
    s.sendto(b, (host, port))
    if i % 10 == 9:
        time.sleep(0.01)          # at most ~1000 datagrams/s: all reach the bridge
    if time.time() - t0 > 20:
        break
print(f"sent {i + 1} hostile datagrams in {time.time() - t0:.2f} s")
