"""Shared rclpy plumbing: QoS, message helpers, diagnostics, and running a node until
SIGINT / SIGTERM with one-line errors.  Parameters: :mod:`.parameters`; waiting for a node
to become active: :mod:`.readiness`."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import NoReturn

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from damper_emulator.bag import BagError
from damper_emulator.bag.cdr_fast import JointStateCodec, JointStateDecoder, JointStateSample
from damper_emulator.realtime.rt import (
    GIL_SWITCH_INTERVAL_S,
    RealtimeRequest,
    ThreadInheritance,
    apply_realtime,
)
from damper_emulator.ros.parameters import flatten
from damper_emulator.schema import ParameterError

PROG = "damper-hil"


def executor_priority(loop_priority: int) -> int:
    """SCHED_FIFO priority of the executor (main) thread of a node whose real-time thread
    runs at ``loop_priority`` (``main_thread_priority``; see :func:`spin_node`): just below
    it.  The executor thread shares the GIL with that thread; any lower and another
    process's real-time thread could keep it off the CPU while it holds the GIL.  It does
    little work (diagnostics, services), so the high priority costs the others little."""
    return max(1, int(loop_priority) - 1)


def control_qos(depth: int, reliable: bool = True) -> QoSProfile:
    """Volatile, keep-last ``depth``; reliable (every publisher of the project's topics,
    and the subscribers that need every sample) or best effort (``reliable=False``: the
    inputs of a loop that runs on its own clock, see :mod:`.topics`)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=DurabilityPolicy.VOLATILE)


class JointStateIn:
    """The JointStates of a raw subscription (``create_subscription(..., raw=True)``),
    decoded by a :class:`~damper_emulator.bag.cdr_fast.JointStateDecoder`, at a fraction
    of an rclpy message object's cost (benchmarks/message_bench.py).

    :meth:`decode` gives the sample, or the one-line reason why ``data`` is not a
    JointState (a publisher's bug: rclpy would have refused it before the callback).
    """

    def __init__(self) -> None:
        self._decoder = JointStateDecoder()

    def decode(self, data: bytes) -> JointStateSample | str:
        try:
            return self._decoder.decode(data)
        except BagError as exc:
            return str(exc)


class JointStateOut:
    """Publish JointStates of one layout on ``publisher`` as CDR bytes from a
    :class:`~damper_emulator.bag.cdr_fast.JointStateCodec`.

    Parameters
    ----------
    publisher : rclpy Publisher (or LifecyclePublisher) of ``sensor_msgs/msg/JointState``
    names : sequence of str
    counts : (int, int, int)
        Lengths of ``position``, ``velocity`` and ``effort``.
    """

    def __init__(self, publisher, names: Sequence[str], counts: tuple[int, int, int]):
        self.publisher = publisher
        self._codec = JointStateCodec(names, counts)

    def publish(self, stamp_ns: int, values: Sequence[float]) -> None:
        """``values``: ``position``, ``velocity`` and ``effort`` one after the other."""
        self.publisher.publish(self._codec.encode(stamp_ns, values))


# --------------------------------------------------------------------------------------
# messages


def publish_diagnostics(node: Node, publisher, name: str, level, message: str,
                        hardware_id: str, values: Mapping[str, str]) -> None:
    """One ``DiagnosticStatus`` (``values`` as key/value pairs) in a ``DiagnosticArray``
    stamped now, on ``publisher`` (``/diagnostics``)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    status = DiagnosticStatus(level=level, name=name, message=message,
                              hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=v) for k, v in values.items()])
    array = DiagnosticArray(status=[status])
    array.header.stamp = node.get_clock().now().to_msg()
    publisher.publish(array)


def set_stamp(stamp, ns: int) -> None:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    stamp.sec = sec
    stamp.nanosec = nsec


# --------------------------------------------------------------------------------------
# running a node


def log_info(node: Node, text: str) -> None:
    """Log through rclpy while the context is up, else to stderr (at shutdown)."""
    if node.context.ok():
        node.get_logger().info(text)
    else:
        print(f"[{node.get_name()}] {text}", file=sys.stderr)


def params_files(ros_args: list[str]) -> list[str]:
    """The files of ``--params-file FILE`` in ROS arguments."""
    return [ros_args[i + 1] for i, a in enumerate(ros_args[:-1]) if a == "--params-file"]


def check_params_file(path: str) -> None:
    """Refuse, in one line naming ``path``, a params file that cannot be read, is not
    YAML, is empty or holds no ``<node>: ros__parameters:`` mapping (rclpy would start
    the node on its defaults without a word)."""
    from damper_emulator.schema import read_yaml

    doc = read_yaml(path)
    if not doc:
        raise ParameterError(f"{path}: empty parameter file (no parameters)")
    if not isinstance(doc, Mapping) or not any(
            isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping)
            and body["ros__parameters"] for body in doc.values()):
        raise ParameterError(f"{path}: no parameters (expected '<node name or /**>: "
                             f"ros__parameters: {{...}}')")


def _file_keys(path: str) -> set[str]:
    from damper_emulator.schema import read_yaml

    try:
        doc = read_yaml(path)
    except ParameterError:
        return set()
    keys: set[str] = set()
    for body in (doc.values() if isinstance(doc, Mapping) else ()):
        if isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping):
            keys |= set(flatten(body["ros__parameters"]))
    return keys


def attribute_to_file(message: str, files: list[str]) -> str:
    """A node's one-line parameter error names the node (``node X parameters: ...``);
    where the offending parameter comes from a ``--params-file``, name that file instead
    (the first that sets it, else every file given)."""
    prefix, sep, rest = message.partition(" parameters: ")
    if not files or not sep or not prefix.startswith("node "):
        return message
    named = [f for f in files if any(k in rest.split() or f"{k}." in rest or
                                     rest.startswith(k) for k in _file_keys(f))]
    source = named[0] if named else ", ".join(files)
    return f"{source} ({prefix}): {rest}"


def _leave_refused() -> NoReturn:
    """End the process with status 2 after a node refused its parameters, without the
    middleware's teardown.  By then the DDS participant is in the domain (the middleware
    threads start with the first node, before the parameters can be read), and nothing
    else is open: no node, file or thread of ours.  The teardown is all that is left, and
    it can wait on the discovery of the processes starting beside it (a refused process
    has been seen to hang there): a refusal must not depend on the middleware's way out.
    The price: the participants beside it see this one, and the node it refused, until
    its lease runs out (Fast DDS: 20 s)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(2)


def spin_node(build: Callable[[], Node], ros_args: list[str]) -> int:
    """Initialise rclpy with ``ros_args``, build the node, spin until SIGINT / SIGTERM or
    until the node calls ``rclpy.try_shutdown`` (a node with a ``run(executor)`` method
    drives the executor itself), then call its ``close()`` (if any) and tear down.  Returns
    the node's ``exit_status`` (default 0).  The middleware threads created while starting
    run under ``SCHED_FIFO`` at the node's ``dds_priority`` when it has one (> 0) and it is
    permitted, else under the normal policy.

    A node class whose ``OWN_SIGNALS`` is true (a managed node,
    :class:`~damper_emulator.ros.managed.ManagedNode`) handles SIGINT and SIGTERM itself:
    rclpy installs no handler of its own, which would shut the context down at once and
    leave the node no way to send its safe output.

    A :class:`ParameterError` or ``ValueError`` while building is one line on stderr and
    exit status 2; the process then leaves at once (:func:`_leave_refused`).
    """
    from rclpy.signals import SignalHandlerOptions

    own_signals = bool(getattr(build, "OWN_SIGNALS", False))
    # A loop thread waiting for the GIL waits at most this long for a Python thread that
    # holds it (default 5 ms, several loop periods).
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # the middleware's threads (DDS receive, events) are created by init and the first
    # node of the context: let them start under SCHED_FIFO, then set them as the node asks
    # (``dds_priority``, 0 = normal scheduling).  Only that runs at the inherited real-time
    # priority: a node's own start-up (its model, warm-up, road) must not, or it keeps
    # other processes' threads of the same priority off the CPU for seconds.
    files = params_files(ros_args)
    try:
        for f in files:    # before rcl reads them: one line of ours, not rcl's two
            check_params_file(f)
    except ParameterError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    inherit = ThreadInheritance()
    with inherit:
        try:
            rclpy.init(args=["--ros-args", *ros_args] if ros_args else None,
                       signal_handler_options=SignalHandlerOptions.NO if own_signals
                       else None)
        except _rclpy_impl.RCLError as exc:   # a malformed --ros-args: one line
            print(f"{PROG}: error: --ros-args: {' '.join(str(exc).split())}",
                  file=sys.stderr)
            return 2
        rclpy.create_node(f"{PROG.replace('-', '_')}_start").destroy_node()
    node = None
    status = 0
    try:
        try:
            node = build()
        except (ParameterError, ValueError, BagError) as exc:
            print(f"{PROG}: error: {attribute_to_file(' '.join(str(exc).split()), files)}",
                  file=sys.stderr)
            _leave_refused()
        finally:
            settled = inherit.settle(int(getattr(node, "dds_priority", 0)))
        if getattr(node, "dds_priority", 0):
            log_info(node, settled)
        main_priority = int(getattr(node, "main_thread_priority", 0))
        if main_priority:
            # The executor thread shares the GIL with the node's SCHED_FIFO loop: left at
            # normal priority it can be preempted by other processes' real-time threads
            # while it holds the GIL, and the loop then waits for it (a priority inversion;
            # see executor_priority).
            report = apply_realtime(RealtimeRequest(sched_fifo=True, priority=main_priority,
                                                    lock_memory=False))
            log_info(node, f"executor thread: {report.summary()}")
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        run = getattr(node, "run", None)
        try:
            if run is not None:
                run(executor)       # the node drives the executor itself
            else:
                executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        status = int(getattr(node, "exit_status", 0))
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return status


# --------------------------------------------------------------------------------------
# stopping on a signal, for nodes that handle SIGINT and SIGTERM themselves

#: How often a node that handles its stop signals itself looks for one [s].
SIGNAL_POLL_S = 0.2


class StopSignals:
    """SIGINT and SIGTERM noted, not acted on at once: for a node class whose
    ``OWN_SIGNALS`` is true (:func:`spin_node` then installs no rclpy handler, whose first
    act is to shut the context down) and which must still publish, drain or close things
    when it is stopped.  Create it on the main thread.

    :attr:`name` is the first signal's name (``""``: none yet); :meth:`spin` serves the
    executor's callbacks until one arrives or the context is shut down.
    """

    def __init__(self) -> None:
        import signal

        self.name = ""
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._note)

    def _note(self, signum: int, _frame: object) -> None:
        import signal

        # Python runs this on the main thread between two spins: only note it there
        self.name = self.name or signal.Signals(signum).name

    def __bool__(self) -> bool:
        return bool(self.name)

    def spin(self, executor, context) -> None:
        """Spin ``executor`` until a stop signal or the end of ``context``; the signal is
        seen within :data:`SIGNAL_POLL_S`."""
        while context.ok() and not self.name:
            executor.spin_once(timeout_sec=SIGNAL_POLL_S)


# --------------------------------------------------------------------------------------
# taking messages without an executor

#: A :class:`SubscriptionThread`'s longest wait, so that it notices a stop [ns].
INPUT_WAIT_NS = 50_000_000


def take_all(sub):
    """Every message waiting on the rclpy subscription ``sub``, oldest first, as
    ``(message, info)`` (taken directly, without an executor)."""
    while True:
        with sub.handle:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
        if taken is None:
            return
        yield taken


def _ignore(_msg) -> None:
    """Callback of subscriptions whose messages a :class:`SubscriptionThread` takes."""


class SubscriptionThread:
    """Handle the messages of some subscriptions on a thread of their own, without an
    executor: rclpy's executor costs about 0.4 ms of Python per message, half a core at
    1 kHz, and its queue falls behind when the CPU is short.

    The subscriptions live on a second node of ``node``'s context that no executor spins;
    the thread waits on them in one wait set and calls each handler with every message
    taken, oldest first, under the :class:`RealtimeRequest` given (SCHED_FIFO when
    permitted).  An exception in a handler is logged and shuts the context down (the node
    exits with status 1, :attr:`failed`).

    Parameters
    ----------
    node : Node
        The node whose context and logger are used.
    inputs : sequence of (msg_type, topic, handler)
    qos : QoSProfile
    name : str
        Thread name (also the OS thread's).
    realtime : RealtimeRequest, optional
    raw : bool or collection of str
        Hand the handlers the serialized CDR (``bytes``) instead of messages: of every
        input, or of the topics named (the polled ones too).
    polled : sequence of (msg_type, topic)
        Inputs that do not wake the thread: each keeps only its latest message (depth 1,
        best effort), which :meth:`latest` takes.  Every wake-up costs some tens of µs
        in the middleware's wait; a value sampled on a cycle of its own need not pay it
        at the rate it is published.
    after_wake : callable, optional
        ``after_wake(now_ns)`` after the handlers of each wake-up (and each wait that
        timed out); it returns the longest the next wait may last [ns], or None.
    """

    def __init__(self, node: Node, inputs, qos, name: str, realtime=None,
                 raw: bool | Sequence[str] = False, polled: Sequence = (),
                 after_wake: Callable[[int], int | None] | None = None):
        import threading

        def is_raw(topic: str) -> bool:
            return raw if isinstance(raw, bool) else topic in raw

        self._node = node
        self._io_node = rclpy.create_node(f"{node.get_name()}_input", context=node.context)
        self._inputs = [(self._io_node.create_subscription(
            t, topic, _ignore, qos, raw=is_raw(topic)), handler) for t, topic, handler in inputs]
        self._polled = {topic: self._io_node.create_subscription(
            t, topic, _ignore, control_qos(1, reliable=False), raw=is_raw(topic))
            for t, topic in polled}
        self._after_wake = after_wake
        self._realtime = realtime
        self._stop = threading.Event()
        self.failed = False
        self.report = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def latest(self, topic: str):
        """The newest message of the polled input ``topic`` that arrived since the last
        call, else None."""
        newest = None
        for msg, _info in take_all(self._polled[topic]):
            newest = msg
        return newest

    @property
    def io_node(self) -> Node:
        """The node that holds the subscriptions (for graph queries)."""
        return self._io_node

    def stop(self, timeout_s: float = 2.0, drain: bool = False) -> None:
        """Stop the thread; with ``drain``, then hand the handlers (on the caller's thread)
        every message still queued, which the middleware has already acknowledged to its
        publishers (the recorder's last messages)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        if drain and self._io_node is not None and self._node.context.ok() \
                and not self._thread.is_alive():
            for sub, handler in self._inputs:
                for msg, _info in take_all(sub):
                    handler(msg)
        if self.report is not None:
            self.report.release()
        if self._io_node is not None:
            self._io_node.destroy_node()
            self._io_node = None

    def _run(self) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as impl

        from damper_emulator.realtime.rt import apply_realtime, set_thread_name

        set_thread_name(self._thread.name)
        if self._realtime is not None:
            self.report = apply_realtime(self._realtime)
        context = self._node.context
        wait_set = impl.WaitSet(len(self._inputs), 0, 0, 0, 0, 0, context.handle)
        after_wake = self._after_wake
        timeout = INPUT_WAIT_NS
        try:
            while not self._stop.is_set() and context.ok():
                wait_set.clear_entities()
                for sub, _ in self._inputs:
                    with sub.handle:
                        wait_set.add_subscription(sub.handle)
                wait_set.wait(timeout)
                for sub, handler in self._inputs:
                    for msg, _info in take_all(sub):
                        handler(msg)
                if after_wake is not None:
                    longest = after_wake(time.monotonic_ns())
                    timeout = INPUT_WAIT_NS if longest is None else \
                        max(0, min(INPUT_WAIT_NS, longest))
        except Exception as exc:  # noqa: BLE001 - reported, then the node stops
            if not self._stop.is_set():
                self._node.get_logger().error(f"{self._thread.name} thread stopped: {exc!r}")
                self.failed = True
                rclpy.try_shutdown(context=context)
