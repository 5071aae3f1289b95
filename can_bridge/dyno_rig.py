"""A physical damper dyno on the CAN bus as the virtual dyno's engine (``damper-hil dyno
--can-interface ...`` without ``--over-can``).

:class:`RigEngine` is a drop-in for the offline model in :mod:`damper_emulator.dyno.runner`
(:data:`~damper_emulator.dyno.simulated.Engine`): each protocol's stroke history, resampled
to the dyno's cycle (``DYNO_FEEDBACK``'s cycle time), is run on the dyno through the
``DYNO_*`` messages by a :class:`~ride_sim.hybrid.protocol_host.ProtocolHost` (settle, the
transfer system's identification, the history compensated, the safety layer throughout)
and the stroke and force the dyno measured come back, resampled onto the protocol's times:
the measured data record them (a sample whose cycle's feedback never came is left out, not
held).  A run the safety layer stops raises :class:`RigStopped`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from can_bridge.bus import BusConfig
from can_bridge.can_log import CanLog
from can_bridge.dbc import cycle_time_s
from can_bridge.hybrid_link import FEEDBACK, run_hybrid_link
from damper_emulator.realtime.rt import RealtimeRequest
from ride_sim.hybrid.params import HybridConfig
from ride_sim.hybrid.protocol_host import ProtocolHost
from ride_sim.hybrid.rig_host import fit_worker, measured_samples
from ride_sim.hybrid.safety import RunStopped


class RigStopped(RunStopped):
    """The safety layer stopped a protocol on the dyno (one line: why; ``timing``: the
    watchdog or a stall of the host did, :class:`~ride_sim.hybrid.safety.RunStopped`)."""


class RigEngine:
    """Runs protocols on the dyno of ``bus`` (see the module docstring).

    Parameters
    ----------
    bus : BusConfig
    db : cantools.database.can.Database
        With the ``DYNO_*`` messages.
    config : HybridConfig
        Its ``hybrid`` (settle, approach, connect, fit), ``compensator`` and ``safety``.
    realtime : RealtimeRequest, optional
        For the loop's thread.
    progress : callable, optional
        Called with one line per phase.
    can_log : CanLog, optional
        Gets every frame of every run (:class:`~can_bridge.can_log.CanLog`).
    """

    def __init__(self, bus: BusConfig, db: Any, config: HybridConfig, *,
                 realtime: RealtimeRequest | None = None,
                 progress: Callable[[str], None] | None = None,
                 can_log: CanLog | None = None) -> None:
        self.bus = bus
        self.db = db
        self.config = config
        self.realtime = realtime
        self.progress = progress
        self.can_log = can_log
        period = cycle_time_s(db.get_message_by_name(FEEDBACK))
        self.dt_s = float(period) if period else 1e-3
        self.runs: list[dict[str, Any]] = []
        self._executor = fit_worker("rig-fit")
        self.stop = threading.Event()

    def close(self) -> None:
        self._executor.close()

    def __call__(self, model: Any, t: Any, x: Any, v: Any) -> SimpleNamespace:
        t = np.asarray(t, dtype=float)
        x = np.asarray(x, dtype=float)
        grid = np.arange(t[0], t[-1] + 0.5 * self.dt_s, self.dt_s)
        history = np.interp(grid, t, x)
        c = self.config
        host = ProtocolHost(c.hybrid, c.compensator, c.safety, history, self.dt_s,
                            executor=self._executor)
        host.warm_up()
        stats = run_hybrid_link(self.bus, self.db, host, self.stop, realtime=self.realtime,
                                progress=self.progress, can_log=self.can_log)
        run: dict[str, Any] = {"samples": int(grid.size), "phase_at_end": host.phase,
                               "reason": host.reason or "", "link": stats.summary(),
                               "identification": host.identification_report()}
        if host.transfer is not None:
            run["transfer"] = host.transfer.to_dict()
        fresh = measured_samples(host)
        run["samples_without_measurement"] = int(host.k - fresh.size)
        run["samples_measured_late"] = host.placed_late
        if fresh.size > 10:
            target, measured = host.record[0, fresh], host.record[2, fresh]
            error = measured - target
            run["tracking_nrms"] = float(np.sqrt(np.mean(error ** 2) / np.mean(target ** 2)))
            run["peak_error_m"] = float(np.max(np.abs(error)))
        self.runs.append(run)
        if host.phase != "done":
            if host.failure is not None and host.transfer is None:
                raise RigStopped(host.failure)
            raise RigStopped(host.reason or f"the run ended in phase {host.phase}",
                             timing=host.safety.timing)
        if fresh.size < 2:
            raise RigStopped("the run recorded fewer than 2 measured samples")
        # onto the protocol's times from the measured cycles; a protocol sample whose
        # nearest cycle went without its feedback is marked, and the data leave it out
        stroke = np.interp(t, grid[fresh], host.record[2, fresh])
        force = np.interp(t, grid[fresh], host.record[3, fresh])
        nearest = np.clip(np.rint((t - grid[0]) / self.dt_s).astype(int), 0, host.k - 1)
        return SimpleNamespace(force_n=force, faults=np.zeros(t.size, dtype=np.int64),
                               measured_stroke_m=stroke, measured=host.fresh[nearest])


__all__ = ["RigEngine", "RigStopped"]
