"""Loopback dyno emulation: the virtual dyno's protocols run over CAN against the emulator
node behind the bridge, the way a CAN dyno would drive them
(``damper-hil dyno --over-can``).

:class:`Loopback` starts ``damper-hil emulate`` (``emulator.trigger: input``: one force per
sample, the model advanced by the samples' stamps) and ``damper-hil bridge`` (``mode: dyno``)
as processes on a private ROS domain, unless told that they already run.  Its :meth:`engine`
is a drop-in for the offline model in :mod:`damper_emulator.dyno.runner`: the samples go out
as ``DAMPER_STATE`` frames (:func:`~can_bridge.dyno_client.run_over_can`) and the forces
come back as ``DAMPER_FORCE`` frames.  Every run is compared with the offline model on the
same samples, quantised as the DBC quantises them (:attr:`Loopback.comparisons`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from can_bridge.bus import BusConfig, socketcan_available
from can_bridge.core import STATE
from can_bridge.dbc import load_database
from can_bridge.dyno_client import OverCanError, run_over_can
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment
from damper_emulator.signals import signals_held

#: interface-local IPv6 multicast groups (never leave the host) for private loopback runs
PRIVATE_GROUP_PREFIX = "ff11::d4"
#: The UDP ports of private loopback runs: ``PRIVATE_PORT_BASE + pid % PRIVATE_PORT_SPAN``.
#: python-can binds the port on every address, so the port must be no one else's: above
#: the ports DDS takes for every ROS domain valid on Linux (``7400 + 250 · domain + …``,
#: domains 0..101: below 32900), and above the kernel's default ephemeral range
#: (32768..60999).  (A port under 32900 can be a DDS participant's port of the run's own
#: domain, which follows the process id too; the bridge then cannot open the bus.)
PRIVATE_PORT_BASE = 61000
PRIVATE_PORT_SPAN = 4500
#: A force that came back more than this many sample periods after its state was sent is
#: counted ``late_samples``: the emulator computed it on a stale input (a host stall; the
#: loop's own round trip is about one emulator period, 1 ms)
LATE_PERIODS = 2.0


def default_bus(interface: str | None = None, channel: str | None = None) -> BusConfig:
    """The bus of a loopback run: as given; else ``socketcan`` on ``vcan0`` where the kernel
    has it, else ``udp_multicast`` on a group and port private to this process (python-can
    binds the port on every address, so the port is what keeps concurrent runs apart:
    :data:`PRIVATE_PORT_BASE`)."""
    if interface is None:
        interface = "socketcan" if socketcan_available() else "udp_multicast"
    if channel is None:
        channel = "vcan0" if interface == "socketcan" else (
            f"[{PRIVATE_GROUP_PREFIX}:{os.getpid() & 0xFFFF:x}]:"
            f"{PRIVATE_PORT_BASE + os.getpid() % PRIVATE_PORT_SPAN}"
            if interface == "udp_multicast"
            else "loopback")
    return BusConfig(interface=interface, channel=channel)


def quantised(db, name: str, signal: str, values: np.ndarray) -> np.ndarray:
    """``values`` rounded to the signal's resolution, as the frames carry them."""
    scale = float(db.get_message_by_name(name).get_signal_by_name(signal).scale)
    return np.round(np.asarray(values, dtype=float) / scale) * scale


class Loopback:
    """Emulator + bridge on a CAN bus, and a dyno engine that drives them.  Use as a context
    manager.

    Parameters
    ----------
    bus : BusConfig
    workdir : Path
        Node logs go to ``workdir/logs``.
    params_file : Path, optional
        Damper parameter file for the emulator (default: config/sport.yaml).
    start_nodes : bool
        False: the emulator (``trigger: input``) and a bridge in dyno mode already run on
        ``bus``.
    """

    def __init__(self, bus: BusConfig, workdir: Path, params_file: Path | None = None, *,
                 start_nodes: bool = True, domain_id: int | None = None,
                 progress: Callable[[str], None] | None = None):
        self.bus = bus
        self.db = load_database()
        self.workdir = Path(workdir)
        self.params_file = params_file
        self.start_nodes = start_nodes
        self.domain_id = domain_id
        self.progress = progress or (lambda text: None)
        self.comparisons: list[dict] = []
        self._nodes: list[NodeProcess] = []

    def __enter__(self) -> Loopback:
        if self.start_nodes:
            env = ros_environment(self.domain_id)
            logs = self.workdir / "logs"
            files = [self.params_file] if self.params_file else []
            self.progress(f"      starting emulator (trigger: input) and bridge (dyno) on "
                          f"{self.bus.interface} {self.bus.channel}, ROS_DOMAIN_ID "
                          f"{env['ROS_DOMAIN_ID']}; logs in {logs}")
            try:
                with signals_held():
                    self._nodes.append(NodeProcess("emulator", node_command(
                        "emulate", {"emulator.trigger": "input"}, params_files=files), env,
                        logs))
                with signals_held():
                    self._nodes.append(NodeProcess("bridge", node_command(
                        "bridge", {"can_interface": self.bus.interface,
                                   "can_channel": self.bus.channel, "mode": "dyno"}), env,
                        logs))
            except BaseException:
                # no __exit__ after a failed __enter__: the node started first is stopped
                self.__exit__()
                raise
        return self

    def __exit__(self, *exc) -> None:
        for node in reversed(self._nodes):
            node.stop()
        self._nodes.clear()

    def _check_nodes(self) -> None:
        for node in self._nodes:
            if node.poll() is not None:
                raise OverCanError(f"the {node.name} stopped (exit {node.poll()}): "
                                   f"{node.log_tail(1)}")

    def engine(self, model: DamperModel, t, x, v) -> SimpleNamespace:
        """Forces for the samples ``(t, x, v)`` over CAN (the runner's ``engine``)."""
        self._check_nodes()
        r = run_over_can(t, x, v, self.bus, self.db,
                         settle_gap_s=model.cfg.numerics.settle_gap_s,
                         progress=self.progress)
        self._check_nodes()
        n = len(t)
        if r.received < n:
            raise OverCanError(f"{n - r.received} of {n} forces did not come back over CAN "
                               f"(frames dropped: {r.dropped})")
        if r.stroke_mismatches:
            raise OverCanError(f"{r.stroke_mismatches} forces were computed from another "
                               "sample than the one they were paired with")
        xq = quantised(self.db, STATE, "Stroke", x)
        vq = quantised(self.db, STATE, "Velocity", v)
        offline_q = simulate(model, t, xq, vq).force_n
        offline = simulate(model, t, x, v).force_n
        f_rms = float(np.sqrt(np.mean(offline ** 2)))
        diff_q = r.force_n - offline_q
        diff = r.force_n - offline
        lat = r.latency_s[np.isfinite(r.latency_s)] * 1e3
        rate = float(1.0 / np.median(np.diff(t)))
        self.comparisons.append({
            "samples": n, "rate_hz": rate,
            "force_rms_n": f_rms,
            "rms_diff_vs_offline_quantised_n": float(np.sqrt(np.mean(diff_q ** 2))),
            "relative_rms_vs_offline_quantised": float(np.sqrt(np.mean(diff_q ** 2)) / f_rms),
            "max_abs_diff_vs_offline_quantised_n": float(np.max(np.abs(diff_q))),
            "rms_diff_vs_offline_n": float(np.sqrt(np.mean(diff ** 2))),
            "relative_rms_vs_offline": float(np.sqrt(np.mean(diff ** 2)) / f_rms),
            "round_trip_p50_ms": float(np.percentile(lat, 50)) if lat.size else None,
            "round_trip_p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
            "round_trip_max_ms": float(np.max(lat)) if lat.size else None,
            "late_samples": int(np.count_nonzero(lat > LATE_PERIODS / rate * 1e3)),
            "frames_dropped": r.dropped, "fault_frames": r.fault_frames,
            "status_bits_seen": int(np.bitwise_or.reduce(r.status[r.status >= 0]))
            if (r.status >= 0).any() else 0,
            "send_interval_error_max_ms": round(r.send_interval_error_max_s * 1e3, 3),
            "elapsed_s": round(r.elapsed_s, 2),
        })
        # the emulator's model flag (status bit 8) is the only fault a force frame carries
        return SimpleNamespace(force_n=r.force_n, faults=np.zeros(n, dtype=np.int64))
