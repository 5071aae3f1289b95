#!/usr/bin/env python3
"""What one JointState costs the live nodes' Python, per message; prints a markdown table.

The 1 kHz topics (``/damper/state``, ``/damper/force``, ``/ride/state``) are published
and taken as CDR bytes through :class:`damper_emulator.bag.cdr_fast.JointStateCodec` and
``JointStateDecoder`` (``damper_emulator.ros.common.JointStateOut`` / ``JointStateIn``).
This compares them with what they replace, an rclpy message object, in one process and
one run (ratios, not absolute figures, are what carry over to another machine):

* publish side: build a ``sensor_msgs/msg/JointState`` and serialize it (rclpy's
  ``serialize_message``, the work ``Publisher.publish`` does before the middleware) vs
  ``JointStateCodec.encode``;
* take side: ``deserialize_message`` (what a non-raw take does after the middleware) and
  reading the fields vs ``JointStateDecoder.decode``.

Each figure is the median over ``--repeats`` batches of ``--calls`` calls, with the spread
(min-max of the batches).  The middleware's own cost per publish or take (tens of µs,
the same either way) is not in it.

Usage: ``python benchmarks/message_bench.py [--calls N] [--repeats N]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

from machine import cpu_name

from damper_emulator.bag.cdr_fast import JointStateCodec, JointStateDecoder

NAMES = ["damper", "damper/status"]
VALUES = (0.0123, 2e-4, -0.4, 0.0, -812.5, 0.0)     # /damper/force's layout


def _batches(fn, calls: int, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(calls):
            fn(i)
        out.append((time.perf_counter() - t0) / calls * 1e6)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    codec = JointStateCodec(NAMES, (2, 2, 2))
    decoder = JointStateDecoder()
    stamp = time.time_ns()

    def rclpy_out(i: int) -> bytes:
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp + i, 1_000_000_000)
        m.name = NAMES
        m.position, m.velocity, m.effort = list(VALUES[:2]), list(VALUES[2:4]), \
            list(VALUES[4:])
        return serialize_message(m)

    data = rclpy_out(0)

    def rclpy_in(_i: int) -> float:
        m = deserialize_message(data, JointState)
        return m.effort[0] + m.position[1] + m.header.stamp.nanosec

    def codec_out(i: int) -> bytes:
        return codec.encode(stamp + i, VALUES)

    def codec_in(_i: int) -> float:
        s = decoder.decode(data)
        return s.effort[0] + s.position[1] + s.stamp_ns

    rows = []
    for side, old, new in (("publish (build + serialize)", rclpy_out, codec_out),
                           ("take (deserialize + read)", rclpy_in, codec_in)):
        a = _batches(old, args.calls, args.repeats)
        b = _batches(new, args.calls, args.repeats)
        ratios = [x / y for x, y in zip(a, b, strict=True)]
        rows.append((side, a, b, ratios))
    print(f"# JointState per message: {cpu_name()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}, {args.repeats} batches of {args.calls} calls\n")
    print("| side | rclpy message [µs] | codec [µs] | ratio (spread) |")
    print("|---|---|---|---|")
    for side, a, b, r in rows:
        print(f"| {side} | {statistics.median(a):.2f} ({min(a):.2f}-{max(a):.2f}) | "
              f"{statistics.median(b):.2f} ({min(b):.2f}-{max(b):.2f}) | "
              f"{statistics.median(r):.1f}× ({min(r):.1f}-{max(r):.1f}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
