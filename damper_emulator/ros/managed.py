"""What the project's managed (lifecycle) nodes share: the transitions, the guard that keeps
a node up whatever a lifecycle manager sends, and the safe state on every way out of
``active``.

A managed node of the project (the emulator, the CAN bridge) subclasses
:class:`ManagedNode` and provides five hooks:

``_configure()``
    build what the node needs (model, publishers, bus); return ``None``, or the reason it
    cannot (the transition fails and what was built is released);
``_activate()``
    start the inputs and outputs;
``_leave_active(reason)``
    stop them, then put the outputs in their safe state and say ``reason`` on
    ``/diagnostics``;
``_stop_io()``
    stop the threads that read inputs and publish outputs (no output);
``_release()``
    release what ``_configure`` built.

The transitions are rclpy's (the standard ``lifecycle_msgs`` services); this class adds:

* a request for a transition the current state does not have, by id or by label, is
  refused (``success = False``, a warning naming the transition and the state) and the
  node stays up;
* a hook that raises is a bug: it is logged with its traceback, the transition ends in
  rclpy's ``errorprocessing`` and :meth:`on_error` leaves the outputs in their safe state,
  releases everything and returns the node to ``unconfigured``;
* leaving ``active`` by ``deactivate``, ``shutdown`` or an error always calls
  ``_leave_active`` first;
* SIGINT and SIGTERM (a launch file's Ctrl-C, a service manager's stop) are a ``shutdown``
  transition: from ``active`` the outputs go to their safe state, with the signal as the
  reason, and every subscriber has what was published, before the process ends
  (:func:`~damper_emulator.ros.common.spin_node` leaves these signals to the node, see
  :attr:`ManagedNode.OWN_SIGNALS`).
"""

from __future__ import annotations

import time
import traceback
from functools import partial

from lifecycle_msgs.msg import State as LifecycleStateMsg
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from damper_emulator import topics
from damper_emulator.managed_settings import ManagedNodeParams
from damper_emulator.params import field_specs
from damper_emulator.realtime.rt import normal_scheduling
from damper_emulator.ros.common import StopSignals
from damper_emulator.ros.parameters import parameter_descriptor
from damper_emulator.ros.readiness import latched_qos, lifecycle_state_topic

#: The managed nodes' own parameter: configure and activate at start
#: (:class:`~damper_emulator.managed_settings.ManagedNodeParams`).
AUTOSTART = "autostart"

#: rclpy's own topics, which the safe output does not wait for.
RCLPY_TOPICS = ("/rosout", "/parameter_events")

#: ``lifecycle_msgs/msg/Transition`` ids by name (``1: "configure"``, ...), for messages.
TRANSITION_NAMES = {getattr(Transition, n): n.removeprefix("TRANSITION_").lower()
                    for n in dir(Transition) if n.startswith("TRANSITION_")}

#: The primary states' ids by label.
PRIMARY_STATES = {"unconfigured": LifecycleStateMsg.PRIMARY_STATE_UNCONFIGURED,
                  "inactive": LifecycleStateMsg.PRIMARY_STATE_INACTIVE,
                  "active": LifecycleStateMsg.PRIMARY_STATE_ACTIVE,
                  "finalized": LifecycleStateMsg.PRIMARY_STATE_FINALIZED}

#: The transitions a lifecycle manager may request in each primary state (the ROS 2
#: managed-node design: design.ros2.org/articles/node_lifecycle.html), by id.
VALID_TRANSITIONS = {
    "unconfigured": (Transition.TRANSITION_CONFIGURE,
                     Transition.TRANSITION_UNCONFIGURED_SHUTDOWN),
    "inactive": (Transition.TRANSITION_CLEANUP, Transition.TRANSITION_ACTIVATE,
                 Transition.TRANSITION_INACTIVE_SHUTDOWN),
    "active": (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_ACTIVE_SHUTDOWN),
    "finalized": (),
}


def describe_transition(transition: Transition) -> str:
    """``'activate'`` for a request by label, ``id 3 (activate)`` for one by id."""
    if transition.label:
        return repr(transition.label)
    return f"id {transition.id} ({TRANSITION_NAMES.get(transition.id, 'no such transition')})"


class ManagedNode(LifecycleNode):
    """Base of the project's managed nodes (module docstring).

    * ``autostart`` (a read-only bool parameter, default true): :meth:`run` configures and
      activates the node itself; false: it waits for a lifecycle manager's transitions on
      the standard ``lifecycle_msgs`` services (``/<name>/change_state``, ``get_state``,
      ...);
    * the latched ``/<name>/lifecycle_state`` topic, which :meth:`announce` publishes at
      every primary state the node reaches (what
      :func:`~damper_emulator.ros.readiness.wait_until_active` reads);
    * :attr:`lifecycle_state`: the primary state last reached;
    * ``exit_status`` (0; 1 when a transition of the autostart failed, or a hook raised);
    * :meth:`run` ends on SIGINT or SIGTERM with a ``shutdown`` transition.
    """

    #: Read by :func:`~damper_emulator.ros.common.spin_node`: the node handles SIGINT and
    #: SIGTERM itself (rclpy's handlers would shut the context down before the node could
    #: publish its safe output).
    OWN_SIGNALS = True

    def __init__(self, name: str, **kwargs: object) -> None:
        super().__init__(name, **kwargs)
        spec = field_specs(ManagedNodeParams, "")[0]
        self.autostart = bool(self.declare_parameter(
            AUTOSTART, ManagedNodeParams().autostart, parameter_descriptor(spec)).value)
        self.exit_status = 0
        self.lifecycle_state = "unconfigured"
        #: the stop signals, once :meth:`run` has installed their handlers
        self._signals: StopSignals | None = None
        self._lifecycle_pub = self.create_publisher(LifecycleStateMsg,
                                                    lifecycle_state_topic(name),
                                                    latched_qos())
        self._guard_change_state()
        self.announce("unconfigured")

    def announce(self, label: str) -> None:
        """Record the primary state ``label`` reached and publish it on the latched
        ``/<name>/lifecycle_state``."""
        self.lifecycle_state = label
        self._lifecycle_pub.publish(LifecycleStateMsg(id=PRIMARY_STATES[label], label=label))

    # ---- the change_state service -------------------------------------------------------

    def _guard_change_state(self) -> None:
        """Refuse, instead of dying on, a transition the current state does not have.

        rclpy 7.1 (Jazzy) looks a transition requested by label up first and answers
        ``success = False`` when the state has none of that label, but triggers one
        requested by id directly: the state machine raises ``RCLError`` ("Transition is
        not registered") inside the service callback, the executor re-raises it and the
        node exits (ros2/rclpy#1209; ros2/rclpy#1319 catches it upstream).  Lifecycle
        managers send ids.  The node's ``change_state`` service therefore calls rclpy's own
        callback and answers ``success = False`` to that error: the state machine raises
        it before it changes anything.
        """
        for service in self.services:
            if service.srv_type is ChangeState:
                service.callback = partial(self._change_state, service.callback)

    def _change_state(self, handle, request: ChangeState.Request,
                      response: ChangeState.Response) -> ChangeState.Response:
        try:
            return handle(request, response)
        except _rclpy_impl.RCLError:
            valid = [TRANSITION_NAMES[t]
                     for t in VALID_TRANSITIONS.get(self.lifecycle_state, ())]
            self.get_logger().warning(
                f"refused lifecycle transition {describe_transition(request.transition)} "
                f"in state '{self.lifecycle_state}': the state has no such transition "
                f"(valid: {', '.join(valid) or 'none'})")
            response.success = False
            return response

    # ---- what a managed node provides ---------------------------------------------------

    def _configure(self) -> str | None:
        """Build what the node needs; ``None``, or why it cannot (one line)."""
        raise NotImplementedError

    def _activate(self) -> None:
        """Start the inputs and outputs."""
        raise NotImplementedError

    def _stop_io(self) -> None:
        """Stop the threads that read inputs and publish outputs."""
        raise NotImplementedError

    def _leave_active(self, reason: str) -> None:
        """Stop the outputs, leave them in the safe state and say ``reason`` on
        ``/diagnostics``."""
        raise NotImplementedError

    def _release(self) -> None:
        """Release what ``_configure`` built (publishers, timers, the bus, ...)."""
        raise NotImplementedError

    # ---- the transitions, the same for every managed node --------------------------------

    def _leave_active_safely(self, reason: str) -> None:
        """:meth:`_leave_active`, then wait (at most
        :data:`~damper_emulator.topics.ACK_TIMEOUT_S`) until every subscriber has
        acknowledged what the node published: where the publishers are destroyed next
        (shutdown, error processing, then the end of the process), a publisher destroyed
        right after a publish takes with it the safe output and what a recorder running
        behind has not yet taken.  (Deactivation keeps the publishers and does not wait.)"""
        self._leave_active(reason)
        deadline = time.monotonic() + topics.ACK_TIMEOUT_S
        for pub in list(self.publishers):
            if pub.topic_name in RCLPY_TOPICS:
                continue
            left = max(0.0, deadline - time.monotonic())
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                self.get_logger().warning(f"{pub.topic_name}: not every subscriber "
                                          f"acknowledged the last output within "
                                          f"{topics.ACK_TIMEOUT_S:g} s")

    def _bug(self, hook: str, exc: BaseException) -> TransitionCallbackReturn:
        """A hook raised: a bug.  Logged with its traceback (rclpy would swallow it); the
        transition ends in ``errorprocessing`` (:meth:`on_error`)."""
        self.get_logger().error(
            f"bug: the {hook} transition raised {type(exc).__name__}: {exc}\n"
            + "".join(traceback.format_exception(exc)).rstrip())
        self.exit_status = 1
        return TransitionCallbackReturn.ERROR

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            # the build (the model's compiled code loaded or compiled, exercised) is not
            # real-time work: under the executor's SCHED_FIFO it takes a CPU from other
            # processes' loops for as long (seconds with an empty kernel cache)
            with normal_scheduling():
                problem = self._configure()
        except Exception as exc:  # noqa: BLE001 - a bug: logged, then on_error
            return self._bug("configure", exc)
        if problem:
            self.get_logger().error(f"configure failed: {problem}")
            self._release()
            return TransitionCallbackReturn.FAILURE
        result = super().on_configure(state)
        self.announce("inactive")
        return result

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = super().on_activate(state)     # the lifecycle publishers
        try:
            # nor is the start of the inputs and outputs (a full collection of the
            # heap, then threads that set their own real-time policy)
            with normal_scheduling():
                self._activate()
        except Exception as exc:  # noqa: BLE001 - a bug: logged, then on_error
            return self._bug("activate", exc)
        self.announce("active")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._leave_active("deactivated by a lifecycle transition")
        except Exception as exc:  # noqa: BLE001 - a bug: logged, then on_error
            return self._bug("deactivate", exc)
        self.announce("inactive")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._release()
        except Exception as exc:  # noqa: BLE001 - a bug: logged, then on_error
            return self._bug("cleanup", exc)
        self.announce("unconfigured")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            if state.state_id == LifecycleStateMsg.PRIMARY_STATE_ACTIVE:
                self._leave_active_safely(f"stopped by {self.stop_signal}"
                                          if self.stop_signal
                                          else "shut down by a lifecycle transition")
            self._stop_io()
            self._release()
        except Exception as exc:  # noqa: BLE001 - a bug: logged, then on_error
            return self._bug("shutdown", exc)
        self.announce("finalized")
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition from ``state`` failed with an error: the outputs to their safe
        state (where they may have run: from ``inactive`` or ``active``), everything
        released, back to ``unconfigured``; finalized if even that fails."""
        self.get_logger().error(f"a transition from '{state.label}' failed: outputs to "
                                "their safe state, everything released, back to "
                                "'unconfigured'")
        try:
            if state.state_id in (LifecycleStateMsg.PRIMARY_STATE_INACTIVE,
                                  LifecycleStateMsg.PRIMARY_STATE_ACTIVE):
                self._leave_active_safely(f"a lifecycle transition from '{state.label}' "
                                          "failed")
            self._stop_io()
            self._release()
        except Exception as exc:  # noqa: BLE001 - a bug: logged, the node is finalized
            self._bug("error processing", exc)
            self.announce("finalized")
            return TransitionCallbackReturn.FAILURE
        self.announce("unconfigured")
        return super().on_error(state)

    # ---- running ------------------------------------------------------------------------

    def before_spin(self, executor: SingleThreadedExecutor) -> None:
        """Called by :meth:`run` after the autostart transitions (default: nothing); a
        long wait in it ends when :attr:`stopping`."""

    @property
    def stopping(self) -> bool:
        """A stop signal has arrived."""
        return bool(self._signals)

    @property
    def stop_signal(self) -> str:
        """The name of the signal that stops the node (``""``: none)."""
        return self._signals.name if self._signals is not None else ""

    def run(self, executor: SingleThreadedExecutor) -> None:
        """Autostart (when asked), then serve the lifecycle services and the node's
        callbacks until SIGINT or SIGTERM, which end in a ``shutdown`` transition
        (module docstring), or until the context is shut down."""
        self._signals = StopSignals()
        if self.autostart:
            for name, trigger in (("configure", self.trigger_configure),
                                  ("activate", self.trigger_activate)):
                if self.stopping:
                    break
                if trigger() != TransitionCallbackReturn.SUCCESS:
                    self.get_logger().error(f"autostart: the {name} transition failed")
                    self.exit_status = 1
                    return
            if not self.stopping:
                self.before_spin(executor)
        else:
            self.get_logger().info("autostart false: waiting for a lifecycle manager "
                                   f"(/{self.get_name()}/change_state)")
        self._signals.spin(executor, self.context)
        if self.stopping and self.lifecycle_state != "finalized":
            self.get_logger().info(f"{self.stop_signal}: shutting down from "
                                   f"'{self.lifecycle_state}'")
            self.trigger_shutdown()
