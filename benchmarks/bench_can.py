"""CAN capture throughput on python-can's virtual bus.

Offers the default map's traffic (7 joints x 2 PDOs + SYNC = 15 frames a sample) at
15,000 frames/s for 60 s to the capture's reader (Notifier + BufferedReader +
SampleAssembler), sender and receiver in one process as the virtual bus requires.
Prints frames/s received against offered, frames lost (not received within 0.5 s
after the last one was offered), the process's CPU use, and then offers rising
rates for 5 s each to find the highest rate sustained with no loss.

    .venv/bin/python benchmarks/bench_can.py [seconds at 15k, default 60]
"""

from __future__ import annotations

import sys
import threading
import time
import uuid

import can
import numpy as np

from contactkit.recorder.importers.can_codec import SampleAssembler, session_frames
from contactkit.recorder.importers.can_map import load_map

FRAMES_PER_SAMPLE = 15


def offer(rate_frames: float, seconds: float) -> dict:
    """Offer ``rate_frames`` frames/s for ``seconds``; return what the reader got."""
    fmap = load_map()
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    receiver = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    reader = can.BufferedReader()
    notifier = can.Notifier(receiver, [reader], timeout=0.05)
    assembler = SampleAssembler(fmap)
    samples = int(rate_frames * seconds / FRAMES_PER_SAMPLE)
    t = np.arange(samples) * FRAMES_PER_SAMPLE / rate_frames
    values = np.zeros((samples, 21))
    frames = list(session_frames(fmap, t, values))
    stop = threading.Event()

    def consume() -> None:
        while not stop.is_set() or reader.buffer.qsize():
            msg = reader.get_message(timeout=0.01)
            if msg is not None:
                assembler.feed(msg)

    consumer = threading.Thread(target=consume)
    consumer.start()
    cpu0, wall0 = time.process_time(), time.monotonic()
    batch = max(1, int(rate_frames / 1000))
    for i in range(0, len(frames), batch):
        for msg in frames[i:i + batch]:
            sender.send(msg)
        due = wall0 + (i + batch) / rate_frames
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    offered_s = time.monotonic() - wall0
    deadline = time.monotonic() + 0.5
    while assembler.stats.frames < len(frames) and time.monotonic() < deadline:
        time.sleep(0.01)
    received = assembler.stats.frames
    cpu = time.process_time() - cpu0
    wall = time.monotonic() - wall0
    stop.set()
    consumer.join()
    notifier.stop()
    receiver.shutdown()
    sender.shutdown()
    return {"offered": len(frames), "received": received, "lost": len(frames) - received,
            "offered_per_s": len(frames) / offered_s, "received_per_s": received / wall,
            "cpu": cpu / wall}


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    r = offer(15_000, seconds)
    print(f"15,000 frames/s for {seconds:.0f} s: offered {r['offered_per_s']:.0f}/s, received "
          f"{r['received_per_s']:.0f}/s ({r['received'] / r['offered']:.4f} of offered), "
          f"lost {r['lost']}, CPU {100 * r['cpu']:.0f} % of one core (sender + capture)")
    best = 0
    for rate in (15_000, 20_000, 25_000, 30_000, 40_000, 50_000):
        r = offer(rate, 5.0)
        ok = r["lost"] == 0 and r["offered_per_s"] >= 0.98 * rate
        print(f"  {rate:>6} frames/s offered ({r['offered_per_s']:.0f} achieved by the "
              f"sender): lost {r['lost']}, CPU {100 * r['cpu']:.0f} %"
              + ("" if ok else "  <- not sustained"))
        if not ok:
            break
        best = rate
    print(f"highest offered rate sustained with no loss: {best} frames/s")


if __name__ == "__main__":
    main()
