"""Child process for tests/test_bag.py: record JointState at ~RATE Hz in real time until killed.

Usage: python bag_kill_child.py BAG_DIR [RATE_HZ]

Prints ``ready`` once the bag is open, then ``<timestamp_ns> <index>`` (flushed)
after every message it has handed to the writer. The writer's own background
flush (default period) is the only thing that puts messages on disk.
"""

import sys
import time

from damper_emulator.bag import BagWriter, messages


def main() -> None:
    path = sys.argv[1]
    rate = float(sys.argv[2]) if len(sys.argv) > 2 else 2000.0
    writer = BagWriter(path)
    topic = writer.add_topic("/damper/state", "sensor_msgs/msg/JointState")
    out = sys.stdout
    print("ready", flush=True)
    period = 1.0 / rate
    next_tick = time.monotonic()
    last = 0
    i = 0
    while True:
        stamp = max(time.time_ns(), last + 1)
        data = messages.joint_state(stamp, ["damper"], [i * 1e-3], [float(i)], [-float(i)])
        writer.write(topic, stamp, data)
        out.write(f"{stamp} {i}\n")
        out.flush()
        last = stamp
        i += 1
        next_tick += period
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)


if __name__ == "__main__":
    main()
