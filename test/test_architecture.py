"""The pure-core rule of ARCHITECTURE.md: only */nodes/ modules import rclpy or messages
(benchmarks only inside their run()), and hand_capture never imports hand_control."""

from __future__ import annotations

import ast
import subprocess
import sys

from ros_helpers import ROOT

PACKAGES = ("hand_capture", "hand_control")
_ROS_PREFIXES = ("rclpy", "hand_msgs", "sensor_msgs", "std_msgs", "geometry_msgs",
                 "visualization_msgs", "diagnostic_msgs", "rosgraph_msgs", "lifecycle_msgs",
                 "std_srvs", "rcl_interfaces", "builtin_interfaces")


def _core_modules() -> list[str]:
    mods = []
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            rel = f.relative_to(ROOT)
            if "nodes" in rel.parts:
                continue
            mods.append(".".join(rel.with_suffix("").parts).removesuffix(".__init__"))
    return mods


def _imports(path) -> list[str]:
    tree = ast.parse(path.read_text())
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def test_core_modules_do_not_import_ros_statically() -> None:
    offenders = []
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            # nodes/ are the ROS wrappers; bench/ drives them and imports ROS only inside
            # run() (the next test checks that importing a benchmark loads no rclpy).
            if {"nodes", "bench"} & set(f.relative_to(ROOT).parts):
                continue
            for name in _imports(f):
                if name.split(".")[0] in _ROS_PREFIXES:
                    offenders.append(f"{f.relative_to(ROOT)}: {name}")
    assert not offenders, offenders


def test_importing_every_core_module_leaves_rclpy_unloaded() -> None:
    mods = _core_modules()
    code = ("import importlib, sys\n"
            f"for m in {mods!r}:\n    importlib.import_module(m)\n"
            "bad = sorted(k for k in sys.modules if k.split('.')[0] in "
            f"{_ROS_PREFIXES!r})\nprint(bad)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_hand_capture_never_imports_hand_control() -> None:
    offenders = [str(f.relative_to(ROOT)) for f in (ROOT / "hand_capture").rglob("*.py")
                 if any(n.split(".")[0] == "hand_control" for n in _imports(f))]
    assert not offenders, offenders
