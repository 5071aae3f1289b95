"""Nothing compiles inside a real-time loop, the readiness handshake, where the
compiled kernels are cached, and a first start with a cold cache.

- A fresh process warms up a core (:meth:`EmulatorCore.warm_up`) and a ride session
  (:meth:`RideSession.warm_up`), then runs everything a node can do at run time (every
  extension, the adaptive bypass, every fault output, both triggers); the number of
  compiled kernel specialisations must not grow (it grows on any compile or cache load).
- The emulator is a managed node: ``/damper_emulator/get_state`` answers ``active`` once it
  publishes, and the first ``/damper/force`` of a cold start comes from a warmed model.
- After the install's warm-up, ``identify`` and the discovery compile nothing.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from ros_probe import cold_environment

from damper_emulator.model import jit

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
#: ROS domains of this file (away from the other node tests' and the demo's 40..89)
DOMAINS = {"cold_emulate": 140, "not_ready": 142}  # 141: conftest's demo


def _run_python(code: str, env: dict | None = None, timeout: float = 300) -> str:
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_after_warm_up_nothing_compiles():
    out = _run_python("""
        import dataclasses, math
        from damper_emulator.model import jit
        from damper_emulator.model.compressible import DamperModel
        from damper_emulator.diagnose.truth import (EXAMPLE_EFFECTS, EXAMPLE_TERM,
                                                    example_config, with_extension)
        from damper_emulator.realtime.core import EmulatorCore
        from damper_emulator.realtime.settings import emulator_params_from_mapping
        from ride_sim.params import load_ride_config
        from ride_sim.session import RideSession

        base = DamperModel()
        models = [base] + [DamperModel(example_config(n)) for n in EXAMPLE_EFFECTS]
        models.append(DamperModel(with_extension(base.cfg, "discovered_term",
                                                 EXAMPLE_TERM)))
        params = emulator_params_from_mapping({})
        cores = [EmulatorCore(m, params) for m in models]
        rc = load_ride_config()
        session = RideSession(rc.quarter_car, rc.road, rc.ride, rc.simulation.step_s,
                              cores[0].static_force_n)
        for c in cores:
            c.warm_up()
        session.warm_up()
        ready = jit.compiled_signatures()

        # what the nodes do at run time, in every mode
        for c in cores:
            for mode in ("hold", "extrapolate"):
                for fault in ("hold", "zero", "passive"):
                    c.params = dataclasses.replace(params, input_mode=mode, fault_mode=fault)
                    t = 10**9
                    for k in range(300):
                        t += 10**6
                        x = 0.03 * math.sin(k / 20.0)
                        c.submit(t, x, 0.6 * math.cos(k / 20.0), t)
                        if k % 50 == 0:
                            c.set_valve_command((k // 50 % 3) / 2.0)
                            c.stepper.set_temperature(30.0 + k / 10.0)
                        c.tick(t)
                    c.tick(t + 10**9)                              # input timeout
                    c.submit(t, math.nan, 0.0, t)                  # rejected
                    c.reject_malformed("empty JointState")
                    c.tick(t + 2 * 10**9)
            t = 5 * 10**9
            for k in range(200):                                   # trigger: input
                t += 10**6
                c.evaluate(t, 0.02 * math.sin(k / 9.0), 0.4 * math.cos(k / 9.0))
        force = cores[0].static_force_n
        while not session.done:
            x, v = session.motion()
            session.body_velocity()
            session.apply(force + 1000.0 * v, 0)
            session.last()
        print(ready, jit.compiled_signatures())
    """)
    ready, after = map(int, out.split())
    assert ready > 0
    assert after == ready, f"{after - ready} kernel specialisations compiled after warm-up"


def test_cache_lives_outside_the_source_tree_and_is_keyed_by_the_sources(tmp_path):
    assert ROOT not in Path(jit.CACHE_DIR).parents
    key = jit.source_key()
    assert Path(jit.CACHE_DIR).name == f"{jit.CACHE_PREFIX}{key}"
    # a copy of the sources elsewhere gets another key (numba's index is per source
    # path: none of this checkout's kernels is the copy's, nor is its warm-up's mark) ...
    copy = tmp_path / "src"
    for pkg in jit.KEYED_PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            dest = copy / f.relative_to(ROOT)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(f.read_bytes())
    copied = jit.source_key(copy)
    assert copied != key and jit.source_key(copy) == copied
    # ... and with one kernel file changed, another again
    step_file = copy / "damper_emulator" / "model" / "step.py"
    step_file.write_text(step_file.read_text() + "\n# a change\n")
    assert jit.source_key(copy) not in (key, copied)
    # NUMBA_CACHE_DIR (numba's own variable) moves the base
    out = _run_python("from damper_emulator.model import jit; print(jit.CACHE_DIR)",
                      env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "nc")})
    assert Path(out.strip()).parent == tmp_path / "nc"


def test_a_warm_up_fills_the_cache_from_empty_and_marks_it(tmp_path, monkeypatch):
    """The install's warm-up empties a kernel cache that another run filled first (its
    kernels' last bits are that run's), warms it and marks it; a marked cache is kept.
    (The warm-up itself stubbed: ``make`` runs the real one, and the test below runs its
    identification part.)"""
    from damper_hil import warm

    cache = tmp_path / "kernels-0"
    cache.mkdir()
    (cache / "compiled_by_a_diagnosis.nbi").write_text("")
    (cache / "index").mkdir()
    seen: list[list[str]] = []
    monkeypatch.setattr(warm, "cache_directory", lambda: cache)
    monkeypatch.setattr(warm, "warm", lambda: seen.append(sorted(
        p.name for p in cache.iterdir())) or 1.0)
    assert not warm.warmed()
    warm.warm_from_empty()
    assert seen == [[]] and warm.warmed()
    (cache / "loaded_later.nbi").write_text("")
    warm.warm_from_empty()
    assert seen[-1] == ["loaded_later.nbi", warm.MARKER]


def test_a_benchmark_warms_in_another_process_and_loads_the_kernels_itself(tmp_path,
                                                                         monkeypatch):
    """``ensure_warmed`` (the truth benchmark's, the FSAE tool's) warms an unmarked cache
    in another process, never in its own: a process that compiled its kernels runs them as
    compiled, with other last bits than every run that loads them (a diagnosis went
    another way in the process that warmed).  A marked cache is left as it is."""
    from damper_hil import warm

    cache = tmp_path / "kernels-0"
    runs: list[list[str]] = []
    monkeypatch.setattr(warm, "cache_directory", lambda: cache)
    monkeypatch.setattr(warm, "warm", lambda: pytest.fail("warmed in this process"))
    monkeypatch.setattr(subprocess, "run", lambda cmd, check: runs.append(cmd))
    warm.ensure_warmed()
    assert runs == [[sys.executable, "-m", "damper_hil.warm"]]
    cache.mkdir()
    (cache / warm.MARKER).write_text("")
    warm.ensure_warmed()
    assert len(runs) == 1


def test_after_the_installs_warm_up_identify_and_the_discovery_load_every_kernel(tmp_path):
    """The fits' part of the install's warm-up (``warm_fits``, which ``python -m
    damper_hil.warm`` runs in ``make``'s install step) on an empty cache, then in another
    process ``identify`` and the features of ``diagnose``'s discovery (a record's, at a
    second sign width, a zone's profile, a lag), on another damper's files: every kernel
    they run is loaded from the cache, none compiled.  A kernel compiled in the first
    ``identify`` or ``diagnose`` would cost it seconds and give it other last bits than
    every later run (numba's fresh and cached code differ), and a diagnosis can follow
    those bits to another answer.  (Only that part: the whole warm-up costs three times
    the CPU, and ``make`` runs it anyway.)"""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    _run_python("""
        from damper_emulator.model.compressible import DamperModel
        from damper_hil.warm import warm_fits
        warm_fits(DamperModel())
    """, env=env)
    out = _run_python("""
        import gc
        import numpy as np
        from numba.core.registry import CPUDispatcher
        from damper_emulator.diagnose.base import make_record
        from damper_emulator.diagnose.discovery import LAGS_S, Feature, motion
        from damper_emulator.dyno import protocols
        from damper_emulator.dyno.measured import MeasuredData
        from damper_emulator.identify.pipeline import identify
        from damper_emulator.model.compressible import DamperModel, simulate
        from damper_emulator.params import load_config

        model = DamperModel(load_config("config/touring.yaml"))
        rng = np.random.default_rng(5)
        qs, chirp = (MeasuredData(t, x, simulate(model, t, x, v).force_n
                                  + rng.normal(0.0, 4.0, t.size), v)
                     for t, x, v in (protocols.quasi_static(cycles=1),
                                     protocols.chirp(duration_s=6.0)))
        fitted = DamperModel(identify(qs, chirp, load_config("config/touring.yaml")).config)
        m = motion(fitted, make_record(chirp, True), 0.04, 30.0)
        m.terms_at(0.02)
        Feature("z", "N", "position", 0, profile=(0.01, 0.005)).fn(m)
        Feature("l", "-", "lag", 0, lag_s=LAGS_S[-1]).fn(m)
        ours = [d for d in gc.get_objects() if isinstance(d, CPUDispatcher)
                and d.py_func.__module__.startswith(("damper_emulator", "ride_sim"))]
        missed = sorted(f"{d.py_func.__module__}.{d.py_func.__name__}" for d in ours
                        if d.stats.cache_misses)
        print(sum(sum(d.stats.cache_hits.values()) for d in ours), *missed)
    """, env=env)
    hits, *missed = out.split()
    assert int(hits) > 0  # the kernels came from the cache
    assert not missed, f"compiled in the first identify or discovery: {missed}"


def test_cold_emulate_is_active_before_its_first_force(tmp_path):
    """A cold start: `damper-hil emulate` compiles while configuring, answers `active`
    over its lifecycle service, and publishes its first force only then; from that force
    on the outputs flow without a stall."""
    from ros_probe import Probe
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos
    from damper_emulator.ros.launch import NodeProcess, node_command

    env = cold_environment(tmp_path, DOMAINS["cold_emulate"])
    started = time.monotonic()
    emu = NodeProcess("emulator", node_command("emulate"), env, tmp_path)
    probe = Probe(DOMAINS["cold_emulate"])
    forces: list[float] = []
    probe.node.create_subscription(JointState, topics.FORCE,
                                   lambda m: forces.append(time.monotonic()),
                                   control_qos(100))
    try:
        from damper_emulator.ros.readiness import wait_until_active

        waited = wait_until_active(probe.node, "damper_emulator", 120.0,
                                   say=lambda _s: None, executor=probe.executor)
        active_s = time.monotonic() - started
        assert probe.spin_until(lambda: len(forces) >= 1, 30), emu.log_tail()
        first_s = forces[0] - started
        assert probe.spin_until(lambda: len(forces) >= 1000, 30), emu.log_tail()
        gaps = [b - a for a, b in itertools.pairwise(forces)]
    finally:
        probe.close()
        emu.stop()
    log = emu.log_path.read_text()
    report = (f"cold start: active after {active_s:.2f} s (waited {waited:.2f} s), first "
              f"/damper/force after {first_s:.2f} s, largest gap in the first 1000 forces "
              f"{max(gaps) * 1e3:.1f} ms")
    print(report)
    (tmp_path / "cold_start.txt").write_text(report + "\n")
    assert "configured: model exercised" in log
    # nothing compiled once the forces flow (a compile of the step stalls them over a
    # second): the node counts the kernels compiled after 'active' and says so
    assert "compiled after" not in log, log


def test_ride_says_what_it_waits_for_and_fails_in_one_line(tmp_path):
    """No emulator at all: the ride node names what it waited for and exits 1."""
    from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment

    env = ros_environment(DOMAINS["not_ready"])
    ride = NodeProcess("ride", node_command("ride", {"ride.wait_for_emulator_s": 3.0}),
                       env, tmp_path)
    assert ride.wait(120) == 1
    ride.stop()
    log = ride.log_path.read_text()
    assert "waiting for /damper_emulator to become active" in log
    errors = [ln for ln in log.splitlines() if "[ERROR]" in ln]
    assert len(errors) == 1, log
    assert "/damper_emulator did not become active within 3 s" in errors[0], log
    assert "Traceback" not in log
