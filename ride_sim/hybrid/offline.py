"""The host and the virtual rig coupled in one process, without a bus or a wall clock.

The same two cores as a run over CAN (:class:`~ride_sim.hybrid.host.HybridHost`,
:class:`~ride_sim.hybrid.rig.VirtualRig`), on a simulated timeline: the rig's cycle ``j``
measures at ``j T``; its feedback reaches the host ``feedback_latency_s`` later, the host
answers at once (it runs once per feedback), and the command reaches the rig
``command_latency_s`` after that.  Deterministic: the design check of the compensator, the
tests of the loop's logic, and the benchmark's offline column.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ride_sim.hybrid.host import HybridHost
from ride_sim.hybrid.rig import Feedback, VirtualRig
from ride_sim.hybrid.rig_host import LATE_CYCLES, MISSED_FEEDBACK_PERIODS

#: Frame times on a 500 kbit/s bus, about one 8-byte frame each way [s].
FEEDBACK_LATENCY_S = 0.25e-3
COMMAND_LATENCY_S = 0.25e-3


@dataclass(frozen=True)
class Disturbance:
    """What goes wrong during an offline run (times on the rig's clock from its start)."""

    #: from this time on, the rig's transport delay is ``new_delay_s``
    delay_change_at_s: float | None = None
    new_delay_s: float = 0.0
    #: from this time on, no feedback reaches the host
    feedback_cut_at_s: float | None = None
    #: every n-th feedback frame is lost (a corrupted frame the host drops); 0: none
    drop_every: int = 0
    #: the host stalls over each ``(start_s, length_s)`` (a virtual machine's halt): it
    #: sends nothing, and at the stall's end runs a cycle on each feedback that arrived
    #: meanwhile, at its arrival time, its command sent then
    host_stalls: tuple[tuple[float, float], ...] = ()
    #: the feedback frames a stall's backlog holds at most (a socket's receive buffer):
    #: the newest beyond are dropped; None: all are kept
    backlog_frames: int | None = None
    #: every n-th feedback frame comes ``late_cycles`` rig cycles late (an adapter that
    #: held it back): its cycle runs without it, on the last measurement, and the host
    #: takes it when it comes as the link does (:meth:`RigHost.late`, placed by the
    #: alive counter; at most :data:`~ride_sim.hybrid.rig_host.LATE_CYCLES`); 0: none
    late_every: int = 0
    late_cycles: int = 1

    def stalled(self, t_s: float) -> float | None:
        """The end of the host stall ``t_s`` falls in, or None."""
        for start, length in self.host_stalls:
            if start <= t_s < start + length:
                return start + length
        return None


def run_offline(host: HybridHost, rig: VirtualRig, *, max_time_s: float = 3600.0,
                disturbance: Disturbance = Disturbance(),
                feedback_latency_s: float = FEEDBACK_LATENCY_S,
                command_latency_s: float = COMMAND_LATENCY_S,
                after_cycle: Callable[[], None] | None = None) -> HybridHost:
    """Run ``host`` against ``rig`` until the host has finished (or ``max_time_s``).

    ``after_cycle`` is called after each of the host's cycles (a recorder's hand-over at
    a point of the run the test chooses, where a real run's thread takes its own).
    Returns the host, its record filled.
    """
    period = rig.period_s
    d = disturbance
    if d.late_every and not 1 <= d.late_cycles <= LATE_CYCLES:
        raise ValueError(f"late_cycles must be 1 … {LATE_CYCLES}, not {d.late_cycles}")
    queued: list[tuple[float, Feedback | None]] = []   # arrived during a host stall
    late: dict[int, Feedback] = {}                     # held back: by the cycle it comes
    released_at = 0.0
    j = 0

    def answer(t_host: float, feedback: Feedback | None, sent_s: float) -> None:
        host.safety.host_wakes(sent_s)          # as the link: the host's own watchdog
        command = host.cycle(t_host, feedback, int(round(t_host * 1e9)), now_s=sent_s)
        host.stamp(int(round(sent_s * 1e9)))
        rig.command(sent_s + command_latency_s, command.stroke_m, command.enable,
                    command.velocity_m_s)
        host.after_send()
        if after_cycle is not None:
            after_cycle()

    while not host.finished and j * period < max_time_s:
        t = j * period
        t_host = t + feedback_latency_s
        if queued and d.stalled(t_host) is None:
            for arrived, feedback in queued:       # the stall ends: its backlog, at once
                if not host.finished:
                    answer(arrived, feedback, released_at)
            # a backlog that ends short of the stall's end (the newest frames dropped):
            # the link's next read finds nothing past its deadline and runs a cycle
            # without feedback then
            if released_at - queued[-1][0] > MISSED_FEEDBACK_PERIODS * period \
                    and not host.finished:
                answer(released_at, None, released_at)
            queued.clear()
        if d.delay_change_at_s is not None and t >= d.delay_change_at_s:
            rig.set_delay(d.new_delay_s)
        feedback = rig.step(t)
        lost = (d.drop_every and (j + 1) % d.drop_every == 0) or (
            d.feedback_cut_at_s is not None and t >= d.feedback_cut_at_s)
        held = late.pop(j, None)
        if held is not None and not host.finished:
            # its cycle ran late_cycles ago; the cycles since (all but this one) after it
            host.late(t_host, held, d.late_cycles - 1)
        if d.late_every and (j + 1) % d.late_every == 0 and not lost:
            late[j + d.late_cycles] = feedback
            feedback, lost = None, True
        end = d.stalled(t_host)
        if end is not None:
            if d.backlog_frames is None or len(queued) < d.backlog_frames:
                queued.append((t_host, None if lost else feedback))
            released_at = end
        else:
            answer(t_host, None if lost else feedback, t_host)
        j += 1
    return host
