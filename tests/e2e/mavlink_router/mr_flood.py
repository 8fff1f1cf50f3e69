"""Flood a UDP port with valid MAVLink frames as fast as one process can (run as a child process).

    python mr_flood.py HOST PORT SYSID TARGET_SYSID SECONDS

Frames are COMMAND_LONG from SYSID/1 to TARGET_SYSID/1 with rolling sequence
numbers; the count sent is printed at the end.
"""

from __future__ import annotations

import socket
import sys
import time

from pymavlink.dialects.v20 import ardupilotmega as v2


def main() -> int:
    host, port, sysid, target, seconds = (
        sys.argv[1],
        int(sys.argv[2]),
        int(sys.argv[3]),
        int(sys.argv[4]),
        float(sys.argv[5]),
    )
    mav = v2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    frames = []
    for seq in range(256):
        mav.seq = seq
        frames.append(bytes(v2.MAVLink_command_long_message(target, 1, 31000, 0, seq, 0, 0, 0, 0, 0, 0).pack(mav)))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect((host, port))
    sent = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for frame in frames:
            try:
                sock.send(frame)
                sent += 1
            except OSError:  # ECONNREFUSED from an ICMP error, ENOBUFS: keep flooding
                pass
    print(f"sent {sent}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
