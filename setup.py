"""What colcon's ament_python build needs beyond pyproject.toml: the ament index
marker, package.xml, the launch files and parameter files under ``share/damper_hil``, and
the node executables under ``lib/damper_hil`` where ``ros2 run`` finds them.

Everything else (metadata, dependencies, the ``damper-hil`` console script) is in
pyproject.toml; ``pip install .`` reads this too (the files land under the environment's
``share/`` and ``lib/``, unused).
"""

from pathlib import Path

from setuptools import setup

PACKAGE = "damper_hil"
ROOT = Path(__file__).resolve().parent


def _files(folder: str, pattern: str) -> list[str]:
    return sorted(str(p.relative_to(ROOT)) for p in (ROOT / folder).glob(pattern))


setup(python_requires=">=3.10,<3.14", data_files=[
    ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
    (f"share/{PACKAGE}", ["package.xml"]),
    (f"share/{PACKAGE}/launch", _files("launch", "*.launch.py")),
    (f"share/{PACKAGE}/config", _files("config", "*.yaml") + _files("config", "*.dbc")),
    (f"lib/{PACKAGE}", _files("scripts", "*")),
])
