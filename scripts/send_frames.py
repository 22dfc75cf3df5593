"""Replay a Kinect recording as live frames: JSON lines over UDP (or stdout) at its frame rate.

The pattern of a Kinect SDK bridge: wherever a body frame arrives (the Kinect SDK's
``BodyFrameArrived``, Azure Kinect's ``k4abt_tracker_pop_result``), build one object
``{"timestamp": s, "joints": [[x, y, z] x 20], "states": [0|1|2 x 20]}`` in the Kinect-20 order
(docs/live.md) and send it as one datagram; ``fpg-gym live --input udp://HOST:PORT`` does the
rest. This script does exactly that from a file.

    python scripts/send_frames.py REC --to udp://127.0.0.1:9000 [--fps 30] [--end]
    python scripts/send_frames.py REC --to - | fpg-gym live --graph default
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time

from fpg_gym.io import read_recording


def main(argv: list[str] | None = None) -> int:
    """Send every frame of a recording, paced at ``--fps`` (0: as fast as possible)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="a Kinect recording (any format fpg-gym reads)")
    parser.add_argument("--to", default="-", help="udp://HOST:PORT or '-' for stdout")
    parser.add_argument("--fps", type=float, default=30.0, help="frames per second (0: no pacing)")
    parser.add_argument("--end", action="store_true", help='send {"end": true} after the frames')
    args = parser.parse_args(argv)

    recording = read_recording(args.recording)
    sock = None
    if args.to != "-":
        host, _, port = args.to.removeprefix("udp://").rpartition(":")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        address = (host, int(port))

    def send(line: str) -> None:
        if sock is None:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()
        else:
            sock.sendto(line.encode("utf-8"), address)

    start = time.perf_counter()
    for i in range(recording.num_frames):
        if args.fps > 0:  # pace: frame i leaves at start + i / fps
            delay = start + i / args.fps - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        frame = {
            "timestamp": float(recording.timestamps[i]),
            "joints": recording.positions[i].astype(float).tolist(),
            "states": recording.states[i].astype(int).tolist(),
        }
        send(json.dumps(frame, separators=(",", ":")))
    if args.end:
        send('{"end": true}')
    return 0


if __name__ == "__main__":
    sys.exit(main())
