"""The closed-loop HIL demo (``damper-hil demo``, ``make demo``): the emulator, the ride
simulation, the CAN bridge and the recorder as separate ROS 2 processes on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, own ``ROS_DOMAIN_ID``), with the skyhook
controller as its own process on the CAN bus, then a report from the recorded bag
(:mod:`damper_hil.hil_report`).

The control loop of ``control: skyhook``: ride_sim → ``/ride/state`` → bridge (controller
mode) → ``VEHICLE_MOTION`` frames → skyhook process → ``VALVE_COMMAND`` frames → bridge →
``/damper/valve_command`` → emulator (solenoid lag, bypass).  ``control: passive`` starts the
bridge but no controller, so the damper stays at the bridge's fail-safe command (sport).
The bus is ``socketcan`` on ``vcan0`` where the kernel has it, else ``udp_multicast`` on an
interface-local group and port private to the run.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from can_bridge.loopback import default_bus
from damper_emulator import topics
from damper_emulator.errors import DamperHilError
from damper_emulator.recording import read_recording
from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment
from damper_emulator.signals import signals_held
from damper_hil.hil_report import write_report
from ride_sim import loop_delay
from ride_sim.params import load_ride_config
from ride_sim.road import RoadError
from ride_sim.session import check_run_road

#: Seconds allowed beyond the ride's own length for start-up and shut-down.
START_STOP_ALLOWANCE_S = 120.0


class DemoError(DamperHilError, RuntimeError):
    """The demo could not complete (one line, with the failing node's log)."""


def check_ride(duration_s: float) -> None:
    """Raise :class:`DemoError` before any node starts if the ride node would refuse a run
    of ``duration_s`` on its road (a road shorter than the band's longest wavelength)."""
    cfg = load_ride_config()
    run = dataclasses.replace(cfg.ride, duration_s=duration_s)
    try:
        check_run_road(cfg.road, run, cfg.simulation.step_s)
    except RoadError as exc:
        raise DemoError(f"a ride of {duration_s:g} s at {run.speed_m_s:g} m/s: {exc}"
                        ) from None


def _clear_bag(bag: Path) -> None:
    """Remove a previous demo's bag; refuse anything that is not one."""
    if not bag.exists():
        return
    if not bag.is_dir() or not ((bag / "metadata.yaml").is_file() or not any(bag.iterdir())):
        raise DemoError(f"{bag} exists and is not a bag from an earlier demo; not removing it")
    shutil.rmtree(bag)


CONTROLS = ("skyhook", "passive")
#: How long the demo waits for the emulator to become active (a first run compiles its
#: kernels: some seconds on a 2-core machine) [s].
READY_TIMEOUT_S = 120.0
#: Each readiness question's own limit, so that a node that died meanwhile is noticed [s].
READY_POLL_S = 2.0


def _wait_until_ready(env: dict, helpers: list, progress: Callable[[str], None],
                      start_rest: Callable[[], tuple[tuple[str, str], ...]]
                      ) -> tuple[float | None, float]:
    """Wait until the emulator's lifecycle state is ``active`` (its kernels loaded and
    exercised, its loop running), saying how long it took; then start the other nodes
    (``start_rest``, which adds them to ``helpers``) and wait until, for each ``(topic,
    node)`` it returns, that node subscribes to that topic (the recorder and the live
    view, so that they see the ride from its start).  One line if a node dies or time runs
    out.  The emulator starts alone (the others' start-up beside it on two cores slowed
    it), and the time to active is the node's own (its log's stamp of ``active``, from its
    launch): the demo's probe may see it a DDS discovery round later.  Returns that time
    (None where its log does not say) and the probe's [s]."""
    from damper_emulator.ros.emulator import NODE_NAME
    from damper_emulator.ros.readiness import NotReadyError, ReadinessProbe

    progress(f"      waiting for /{NODE_NAME} to become active (a first run compiles its "
             f"kernels)")
    deadline = time.monotonic() + READY_TIMEOUT_S
    started = time.monotonic()
    launched = time.time() - (started - helpers[0].started)

    def check_helpers() -> None:
        for node in helpers:
            if node.poll() is not None:
                raise DemoError(f"the {node.name} stopped (exit {node.poll()}) before "
                                f"the ride started: {node.log_tail(1)}")

    with ReadinessProbe(int(env["ROS_DOMAIN_ID"]), "demo_readiness") as probe:
        while True:
            check_helpers()
            try:
                probe.wait(NODE_NAME, READY_POLL_S, say=lambda _line: None)
                break
            except NotReadyError as exc:
                if time.monotonic() > deadline:
                    raise DemoError(f"{exc} (waited {READY_TIMEOUT_S:g} s)") from None
        seen = time.monotonic() - started
        own = _active_after(helpers[0], launched)
        progress(f"      /{NODE_NAME} active after {own if own is not None else seen:.1f} s"
                 + (f" (seen here after {seen:.1f} s: the discovery's)"
                    if own is not None and seen - own >= 0.5 else ""))
        for topic, name in start_rest():
            while not any(e.node_name == name
                          for e in probe.node.get_subscriptions_info_by_topic(topic)):
                check_helpers()
                if time.monotonic() > deadline:
                    raise DemoError(f"/{name} did not subscribe to {topic} within "
                                    f"{READY_TIMEOUT_S:g} s")
                time.sleep(READY_POLL_S / 20)
            progress(f"      /{name} subscribed to {topic}")
    return own, seen


#: the emulator's log line that says it is active (:class:`EmulatorNode`), after the
#: ``[LEVEL] [stamp] [name]: `` prefix of rclpy's console log
ACTIVE_LINE = "]: active: publishing"


def _active_after(emulator, launched_s: float) -> float | None:
    """Seconds from the emulator's launch (``launched_s``, the wall clock) to its log's
    stamp of becoming active, or None when its log does not say so."""
    try:
        for line in emulator.log_path.read_text(errors="replace").splitlines():
            if ACTIVE_LINE in line:
                return float(line.split("[")[2].split("]")[0]) - launched_s
    except (OSError, IndexError, ValueError):
        pass
    return None


def run_demo(out: Path, duration_s: float = 20.0, *, clock: str = "realtime",
             control: str = "skyhook", domain_id: int | None = None,
             live_port: int | None = None, mf4: bool = False,
             progress: Callable[[str], None] = print) -> dict:
    """Run the demo into ``out`` and return its summary (also ``out/demo.json``); with
    ``live_port``, also the live view (``damper-hil live``) on that port; with ``mf4``, the
    recording's time series as ``out/demo.mf4`` too."""
    started = time.monotonic()
    if control not in CONTROLS:
        raise DemoError(f"control must be one of {', '.join(CONTROLS)}, got {control!r}")
    check_ride(duration_s)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    _clear_bag(bag)
    logs = out / "logs"
    stats = out / "emulator_loop.npz"
    metrics = out / "ride_metrics.json"
    sky_json = out / "skyhook.json"
    for f in (stats, metrics, sky_json):
        f.unlink(missing_ok=True)
    bus = default_bus()
    env = ros_environment(domain_id)
    emulator_params = {"emulator.stats_file": str(stats)}
    if clock == "lockstep":
        emulator_params["emulator.trigger"] = "input"
    progress(f"[1/4] starting the emulator (ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}, "
             f"localhost only; logs in {logs})")
    helpers: list[NodeProcess] = []
    ride = None

    def start(name: str, command: list[str], first: bool = False) -> None:
        """Start a node into ``helpers`` (``first``: at its head, stopped last) under
        signals_held: a Ctrl-C or a kill that lands as it starts still finds it there when
        the finally below stops them."""
        with signals_held():
            node = NodeProcess(name, command, env, logs)
            helpers.insert(0 if first else len(helpers), node)

    def start_rest() -> tuple[tuple[str, str], ...]:
        from damper_emulator.ros.recorder import NODE_NAME as RECORDER

        progress(f"      recorder, CAN bridge (controller mode) on {bus.interface} "
                 f"{bus.channel}"
                 + (", skyhook controller on the bus" if control == "skyhook" else ""))
        # the recorder first in the list: stopped last, it records everything
        start("recorder", node_command("record", extra=["--out", str(bag)]), first=True)
        start("bridge", node_command("bridge", {
            "can_interface": bus.interface, "can_channel": bus.channel,
            "mode": "controller"}))
        if control == "skyhook":
            start("skyhook", node_command("skyhook", extra=[
                "--can-interface", bus.interface, "--can-channel", bus.channel,
                "--json", str(sky_json)]))
        # the recorder (its input node) and the live view see the ride from its start
        subscribed = ((topics.RIDE_STATE, f"{RECORDER}_input"),
                      (topics.FORCE, f"{RECORDER}_input"))
        if live_port is not None:
            from damper_hil.live_node import INPUT_NODE_NAME

            progress(f"      live view on ws://127.0.0.1:{live_port} (Foxglove or Lichtblick, "
                     "layout config/foxglove_layout.json)")
            start("live", node_command("live", extra=["--port", str(live_port)]))
            subscribed += ((topics.RIDE_STATE, INPUT_NODE_NAME),)
        return subscribed

    try:
        start("emulator", node_command("emulate", emulator_params))
        active_after = _wait_until_ready(env, helpers, progress, start_rest)
        progress(f"[2/4] ride: {duration_s:g} s of minor road, clock {clock}")
        with signals_held():
            ride = NodeProcess("ride", node_command("ride", {
                "ride.duration_s": float(duration_s), "ride.clock": clock,
                "ride.metrics_file": str(metrics),
                "ride.state_subscribers": 3}), env, logs)   # emulator, recorder and bridge
        limit = time.monotonic() + duration_s + START_STOP_ALLOWANCE_S
        last = time.monotonic()
        while ride.poll() is None:
            for node in helpers:
                if node.poll() is not None:
                    raise DemoError(f"the {node.name} stopped (exit {node.poll()}): "
                                    f"{node.log_tail(1)}")
            if time.monotonic() > limit:
                raise DemoError(f"the ride did not finish within {duration_s:g} s + "
                                f"{START_STOP_ALLOWANCE_S:g} s: {ride.log_tail(1)}")
            if time.monotonic() - last >= 5.0:
                last = time.monotonic()
                progress(f"      ... {last - started:.0f} s")
            time.sleep(0.2)
        if ride.poll() != 0:
            raise DemoError(f"the ride node failed (exit {ride.poll()}): {ride.log_tail(1)}")
    finally:
        progress("[3/4] stopping the controller, bridge, emulator and recorder")
        if ride is not None:
            ride.stop()
        for node in reversed(helpers):
            node.stop()
    progress("[4/4] report from the bag")
    ride_doc = json.loads(metrics.read_text())
    late = loop_delay.warning(ride_doc["loop_delay"]) if "loop_delay" in ride_doc else None
    if late:
        progress(f"warning: {late}")
    recording = read_recording(bag)
    car = load_ride_config().quarter_car
    return write_report(out, recording, ride_doc, stats, car.sprung_mass_kg, {
        "mode": "closed-loop HIL over ROS 2",
        "duration_s": duration_s,
        "clock": clock,
        "control": control,
        "can_bus": f"{bus.interface} {bus.channel}",
        "skyhook": json.loads(sky_json.read_text()) if sky_json.is_file() else None,
        "ros_domain_id": int(env["ROS_DOMAIN_ID"]),
        "live_port": live_port,
        "elapsed_s": round(time.monotonic() - started, 1),
        # the emulator's launch to its own stamp of active, and to the demo's probe seeing it
        "emulator_active_after_s": (None if active_after[0] is None
                                    else round(active_after[0], 2)),
        "emulator_seen_active_after_s": round(active_after[1], 2),
    }, mf4=mf4)
