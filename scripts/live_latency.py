"""Latency of ``fpg-gym live`` on a 30 Hz UDP stream (the table in docs/live.md).

For each method: start ``fpg-gym live --input udp://127.0.0.1:PORT``, replay a simulated Kinect
recording with ``scripts/send_frames.py --fps 30 --end``, and report what the live command
printed (frames emitted and dropped, latency from receipt to emission, reconstruction ms) and
the CPU seconds of the live process (``resource.getrusage``).

    python scripts/live_latency.py [--clip dance_b] [--scenario front-many] [--methods a,b]
"""

from __future__ import annotations

import argparse
import json
import resource
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from fpg_gym.io import load_default_clips, write_recording
from fpg_gym.simulate import simulate

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def run_one(method: str, recording: Path, graph: Path) -> dict:
    """One live run; the live command's summary plus its CPU seconds."""
    port = free_port()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    command = [sys.executable, "-m", "fpg_gym.cli", "live", "--graph", str(graph)]
    command += ["--method", method, "--input", f"udp://127.0.0.1:{port}", "--idle-timeout-s", "30"]
    # stdout to a file: an undrained pipe would block the live process (and drop frames)
    sink = tempfile.TemporaryFile(mode="w+")
    live = subprocess.Popen(command, stdout=sink, stderr=subprocess.PIPE, text=True)
    assert live.stderr is not None
    # "listening on ..." once bound, then "ready" once the graph is loaded and warm: the
    # latencies are measured from there (frames sent earlier would wait for the start-up)
    for expected in ("listening", "ready"):
        line = live.stderr.readline()
        if expected not in line:
            raise RuntimeError(f"live did not start: {line}")
    sender = [sys.executable, str(REPO / "scripts" / "send_frames.py"), str(recording)]
    subprocess.run([*sender, "--to", f"udp://127.0.0.1:{port}", "--fps", "30", "--end"], check=True)
    _, err = live.communicate(timeout=600)
    sink.seek(0)
    out = sink.read()
    sink.close()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads(err.strip().splitlines()[-1])["live"]
    summary["cpu_s"] = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    summary["lines_out"] = len(out.splitlines())
    return summary


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", default="spin")
    parser.add_argument("--scenario", default="front-many")
    parser.add_argument(
        "--methods", default="fpg:closed-form,fpg:local-search,fpg:local-search+ragdoll"
    )
    args = parser.parse_args()
    from fpg_gym.graph import default_graph  # after argparse: --help stays fast

    with tempfile.TemporaryDirectory() as folder:
        graph = default_graph(exclude=[args.clip]).save(Path(folder) / "graph.npz")
        clip = load_default_clips([args.clip])[0]
        recording = simulate(clip, args.scenario, seed=0)
        path = write_recording(Path(folder) / "rec.npz", recording)
        print(
            f"{args.clip} / {args.scenario}: {recording.num_frames} frames at 30 Hz over UDP "
            "(localhost); graph without the clip\n"
        )
        print(
            "| method | frames in | out | dropped | latency median / p95 / max (ms) | "
            "reconstruction median (ms) | CPU s (live process) |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for method in args.methods.split(","):
            s = run_one(method, path, graph)
            print(
                f"| {method} | {s['received']} | {s['emitted']} | {s['dropped']} | "
                f"{s['latency_ms_median']:.1f} / {s['latency_ms_p95']:.1f} / "
                f"{s['latency_ms_max']:.1f} | {s['reconstruct_ms_median']:.1f} | "
                f"{s['cpu_s']:.1f} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
