"""The repository is a colcon-buildable ROS 2 package (``damper_hil``,
ament_python).  ``package.xml`` is validated with catkin_pkg; a copy of the repository (its
tracked and unignored files, as a clone has them) is built with ``colcon build`` in a
workspace of its own, and the installed executables run from the workspace's environment
as ``ros2 run`` would run them.  The launch files are loaded where ``launch_ros`` is
importable (a ROS 2 install) and skipped here, where it is not a wheel."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PACKAGE = "damper_hil"
#: the executables of ``ros2 run damper_hil ...`` and the subcommand each runs
EXECUTABLES = {"emulator": "emulate", "bridge": "bridge", "ride": "ride", "record": "record"}
#: pyproject dependency → its rosdep key in package.xml (None: no key in rosdistro; the
#: comment in package.xml says so)
ROSDEP = {"numpy": "python3-numpy", "scipy": "python3-scipy", "numba": "python3-numba",
          "PyYAML": "python3-yaml", "matplotlib": "python3-matplotlib",
          "python-can": "python3-can", "cantools": "python3-cantools-pip",
          "msgpack": "python3-msgpack", "rosbags": "python3-rosbags-pip",
          "ros-jazzy-rclpy": "rclpy", "ros-jazzy-common-interfaces": "sensor_msgs",
          "scikit-learn": "python3-sklearn",
          "dask": None, "pyarrow": None, "threadpoolctl": None, "pint": None, "nptdms": None,
          "asammdf": None}


def test_package_xml_is_valid_and_declares_every_dependency():
    from catkin_pkg.package import parse_package

    pkg = parse_package(ROOT / "package.xml")
    pkg.validate()
    assert pkg.package_format == 3 and pkg.name == PACKAGE
    assert [e.content for e in pkg.exports if e.tagname == "build_type"] == ["ament_python"]
    depends = {d.name for d in pkg.exec_depends}
    assert {"rclpy", "sensor_msgs", "std_msgs", "diagnostic_msgs", "lifecycle_msgs",
            "rcl_interfaces", "launch", "launch_ros"} <= depends
    from importlib import metadata

    assert pkg.version == metadata.version("damper-hil")
    # one licence: the ROS convention's, the same in package.xml, the Python metadata and
    # the LICENSE file
    assert pkg.licenses == ["Apache-2.0"]
    assert metadata.metadata("damper-hil")["License"] == "Apache-2.0"
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    runtime = [r for r in metadata.requires("damper-hil") or [] if "extra ==" not in r]
    assert runtime
    for spec in runtime:
        name = re.split(r"[\[<>=!~ ]", spec, maxsplit=1)[0]
        assert name in ROSDEP, f"{name}: add its rosdep key to package.xml and ROSDEP"
        if ROSDEP[name] is not None:
            assert ROSDEP[name] in depends, name
        else:
            assert name in (ROOT / "package.xml").read_text(), \
                f"{name} has no rosdep key: package.xml's comment must say so"


def _copy_repository(dest: Path) -> None:
    """The files a clone has: tracked, and untracked but not ignored (git ls-files)."""
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others",
                            "--exclude-standard"], cwd=ROOT, capture_output=True,
                           check=True).stdout.decode().split("\0")
    dest.mkdir(parents=True)
    for name in filter(None, files):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    ws = tmp_path_factory.mktemp("ws")
    _copy_repository(ws / "src" / PACKAGE)
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}"}
    res = subprocess.run([str(BIN / "colcon"), "build", "--event-handlers",
                          "console_direct-"], cwd=ws, env=env, capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "Finished <<< damper_hil" in res.stdout + res.stderr
    return ws


def _in_workspace(ws: Path, command: str) -> subprocess.CompletedProcess:
    """``command`` in bash after ``source install/setup.sh``, as a ROS user runs it."""
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}"}
    env.pop("PYTHONPATH", None)
    return subprocess.run(["bash", "-c", f". install/setup.sh && {command}"], cwd=ws,
                          env=env, capture_output=True, text=True, timeout=300)


def test_colcon_installs_the_package_where_ros_tools_look(workspace):
    prefix = workspace / "install" / PACKAGE
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages"
            / PACKAGE).exists()
    share = prefix / "share" / PACKAGE
    assert (share / "package.xml").read_text() == (ROOT / "package.xml").read_text()
    assert {p.name for p in (share / "launch").iterdir()} == {
        "closed_loop.launch.py", "dyno.launch.py", "controller.launch.py",
        "emulator_bridge.launch.py"}
    for name in ("sport.yaml", "emulator.yaml", "bridge.yaml", "quarter_car.yaml",
                 "damper.dbc"):
        assert (share / "config" / name).exists(), name
    for exe in EXECUTABLES:
        path = prefix / "lib" / PACKAGE / exe
        assert path.exists() and os.access(path, os.X_OK), exe


@pytest.mark.parametrize("exe", sorted(EXECUTABLES))
def test_the_installed_executables_run_from_the_workspace(workspace, exe):
    res = _in_workspace(workspace, f"install/{PACKAGE}/lib/{PACKAGE}/{exe} --help")
    assert res.returncode == 0, res.stderr
    assert f"damper-hil {EXECUTABLES[exe]}" in res.stdout


def test_the_workspace_imports_its_installed_copy(workspace):
    """The sourced workspace imports the installed package, not the repository's."""
    where = _in_workspace(workspace, "python3 -c 'import damper_hil; "
                                     "print(damper_hil.__file__)'")
    assert str(workspace / "install") in where.stdout, where.stdout + where.stderr


def test_the_launch_files_describe_the_nodes(workspace):
    pytest.importorskip("launch_ros", reason="launch_ros is not a wheel: needs a ROS 2 "
                                             "install (apt or a workspace)")
    import runpy

    from launch.actions import IncludeLaunchDescription
    from launch_ros.actions import Node

    share = workspace / "install" / PACKAGE / "share" / PACKAGE / "launch"
    for name, nodes_expected, includes in (("emulator_bridge", 2, 0), ("dyno", 0, 1),
                                           ("controller", 0, 1), ("closed_loop", 2, 1)):
        ld = runpy.run_path(str(share / f"{name}.launch.py"))["generate_launch_description"]()
        nodes = [a for a in ld.entities if isinstance(a, Node)]
        assert len(nodes) == nodes_expected, name
        assert all(n.node_executable in EXECUTABLES for n in nodes), name
        assert sum(isinstance(a, IncludeLaunchDescription) for a in ld.entities) == includes
