"""Graph descriptions, the runner (start, clean stop, failing node) and launch files."""

from __future__ import annotations

import ast
import re
import signal
import sys
import time
import types
from pathlib import Path

import pytest
from ros_helpers import ROOT, hand_suite, wait_for

from hand_capture.bag.compare import compare_bags
from hand_capture.bag.sample import write_sample_bag
from hand_capture.dds import PROFILE_VARS, profile_file
from hand_capture.errors import GraphError
from hand_control.cli import parse_overrides
from hand_control.graph import available_graphs, format_value, load_graph, ros_args


def _setup_py_scripts() -> dict[str, str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "NODES":
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no NODES table")


def test_every_graph_names_existing_scripts_and_parameter_files() -> None:
    scripts = _setup_py_scripts()
    assert available_graphs(), "no graph described"
    for name in available_graphs():
        g = load_graph(name)
        assert all(f.is_file() for f in g.params_files)
        for n in g.nodes:
            assert n.executable in scripts, f"{name}: {n.executable} not in setup.py"
            module = scripts[n.executable].split(":")[0]
            assert (ROOT / (module.replace(".", "/") + ".py")).is_file(), module


def _installed_globs() -> list[str]:
    """The glob patterns of setup.py's data_files (what a colcon install puts in share/)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    return [node.args[0].value for node in ast.walk(tree)
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "glob"]


def test_data_files_named_by_parameter_files_are_installed() -> None:
    """Every data/... path a parameter file names exists and is in setup.py's data_files, so
    a colcon install (share/hand_suite) has it too."""
    import fnmatch

    globs = _installed_globs()
    named = set()
    for f in (ROOT / "config").rglob("*.yaml"):
        named |= set(re.findall(r"\b(data/[\w./-]+)", f.read_text()))
    assert named, "no parameter file names a data file"
    for rel in sorted(named):
        path = ROOT / rel
        assert path.exists(), f"{rel} is named but missing"
        files = [path] if path.is_file() else [q for q in path.iterdir() if q.is_file()]
        for q in files:
            r = str(q.relative_to(ROOT))
            assert any(fnmatch.fnmatch(r, g) for g in globs), f"{r} is not installed"


def test_every_launch_file_names_a_described_graph() -> None:
    launch_files = sorted((ROOT / "launch").glob("*.launch.py"))
    assert launch_files
    for f in launch_files:
        graphs = re.findall(r'launch_description\("([a-z_]+)"\)', f.read_text())
        assert graphs == [f.name.removesuffix(".launch.py")], f
        load_graph(graphs[0])


def test_launch_description_builds_the_same_graph(monkeypatch: pytest.MonkeyPatch) -> None:
    """launch/launch_ros are not on PyPI: stand-ins record what the launch file asks for."""
    created: list[dict] = []

    class Rec:
        def __init__(self, *args: object, **kwargs: object) -> None:
            self.args, self.kwargs = args, kwargs
            created.append({"type": type(self).__name__, **kwargs})

    mods = {
        "launch": {"LaunchDescription": lambda actions: actions},
        "launch.actions": {"DeclareLaunchArgument": type("DeclareLaunchArgument", (Rec,), {}),
                           "EmitEvent": Rec, "RegisterEventHandler": Rec,
                           "SetEnvironmentVariable": type("SetEnvironmentVariable", (Rec,), {})},
        "launch.event_handlers": {"OnProcessExit": Rec},
        "launch.events": {"Shutdown": Rec},
        "launch.substitutions": {"LaunchConfiguration": lambda name: f"$({name})",
                                 "EnvironmentVariable": lambda name, default_value="":
                                 f"$(env {name} {default_value})"},
        "launch_ros.actions": {"Node": type("Node", (Rec,), {})},
        "launch_ros": {},
    }
    for name, attrs in mods.items():
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attrs))
    for var in PROFILE_VARS:
        monkeypatch.delenv(var, raising=False)
    from hand_control.graph import launch_description

    actions = launch_description("replay")
    # loopback-only discovery unless the environment sets it (issue #20 item 12), before
    # any node starts
    env = actions[0]
    assert type(env).__name__ == "SetEnvironmentVariable"
    assert env.args == ("ROS_AUTOMATIC_DISCOVERY_RANGE",
                        "$(env ROS_AUTOMATIC_DISCOVERY_RANGE LOCALHOST)")
    nodes = [c for c in created if c["type"] == "Node"]
    graph = load_graph("replay")
    assert [(n["name"], n["executable"]) for n in nodes] == [
        (n.name, n.executable) for n in graph.nodes]
    assert all(n["parameters"][: len(graph.params_files)] == [str(f) for f in graph.params_files]
               for n in nodes)
    # every node gets the Fast DDS profile for large images (hand_capture/dds.py)
    assert all(set(n["additional_env"].values()) == {str(profile_file())} for n in nodes)


def test_unknown_graph_lists_the_valid_ones() -> None:
    with pytest.raises(GraphError, match="available: \\[.*'replay'"):
        load_graph("nope")


def test_ros_args_and_overrides() -> None:
    g = load_graph("replay")
    args = ros_args(g.node("bag_player"), [Path("/p.yaml")], {"rate": 2, "loop": True})
    assert args == ["--ros-args", "-r", "__node:=bag_player", "--params-file", "/p.yaml",
                    "-p", "bag_player:rate:=2", "-p", "bag_player:loop:=true"]
    assert format_value(["/a", "/b"]) == "[/a,/b]"
    assert parse_overrides(["bag_player.rate:=0.5"]) == {"bag_player": {"rate": 0.5}}
    with pytest.raises(Exception, match="node.param:=value"):
        parse_overrides(["rate:=1"])


def test_an_override_beats_the_nodes_entry_in_a_parameter_file(tmp_path: Path) -> None:
    """``hand-suite run G -p node.key:=v`` wins over ``node: {key: ...}`` in the graph's
    files (a bare ``-p key:=v`` loses to a node's own entry, as rcl ranks them)."""
    import rclpy

    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    other: 1\n"
                 "bag_player:\n  ros__parameters:\n    rate: 3.0\n")
    node_spec = load_graph("replay").node("bag_player")
    ctx = rclpy.Context()
    rclpy.init(args=["x", *ros_args(node_spec, [f], {"rate": 0.5})], context=ctx)
    try:
        node = rclpy.create_node("player_under_test", context=ctx)  # renamed by __node
        assert node.get_name() == "bag_player"
        assert node.declare_parameter("rate", 1.0).value == 0.5
        assert node.declare_parameter("other", 0).value == 1
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_bag_roundtrip_graph_runs_to_completion_and_round_trips(tmp_path: Path) -> None:
    src, dst = tmp_path / "src", tmp_path / "dst"
    write_sample_bag(src, duration=1.0)
    p = hand_suite("run", "bag_roundtrip", "-p", f"bag_player.bag:={src}",
                   "-p", f"bag_recorder.output:={dst}")
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 0, out
    assert "required node bag_player finished" in out
    cmp = compare_bags(src, dst)
    assert cmp.same_messages, cmp.mismatches


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_every_node_and_exits_zero(tmp_path: Path, sig: int) -> None:
    src = tmp_path / "src"
    write_sample_bag(src, duration=1.0)
    p = hand_suite("run", "bag_roundtrip", "-p", f"bag_player.bag:={src}",
                   "-p", "bag_player.loop:=true", "-p", f"bag_recorder.output:={tmp_path}/o")
    lines: list[str] = []
    import threading

    threading.Thread(target=lambda: lines.extend(p.stdout), daemon=True).start()
    assert wait_for(lambda: any("subscribed to" in ln for ln in lines), 30.0), lines
    t0 = time.monotonic()
    p.send_signal(sig)
    code = p.wait(timeout=15)
    # the runner escalates to SIGKILL within 4.5 s; the rest is slack for a loaded machine
    assert time.monotonic() - t0 < 8.0
    assert code == 0, "".join(lines)
    assert (tmp_path / "o" / "metadata.yaml").is_file(), "recorder did not finish its bag"


def test_failing_node_is_named_with_one_line_and_graph_exits_nonzero(tmp_path: Path) -> None:
    """A suite error (here a missing bag) is one named line, not a (double) traceback."""
    p = hand_suite("run", "bag_roundtrip", "-p", f"bag_player.bag:={tmp_path}/missing",
                   "-p", f"bag_recorder.output:={tmp_path}/o")
    out, _ = p.communicate(timeout=30)
    assert p.returncode != 0
    assert "Traceback" not in out, out
    assert [ln for ln in out.splitlines() if "bag not found" in ln] == [
        ln for ln in out.splitlines() if "[bag_player]" in ln and "error: bag not found" in ln]
    assert "bag not found" in out
    assert "node bag_player failed with exit code 1" in out


def test_a_node_that_does_not_stop_cleanly_is_named_and_fails_the_run(monkeypatch) -> None:
    """A node that ignores the stop (or fails in its shutdown) is killed, named, and the run
    exits non-zero: e.g. a recorder whose bag was not finished is not a clean stop."""
    import io

    import hand_control.runner as runner
    from hand_control.graph import GraphSpec, NodeSpec

    stubborn = ("import faulthandler, signal, time\n"
                "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
                "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
                "faulthandler.register(signal.SIGUSR1, all_threads=True)  # as run_node\n"
                "def stuck_here():\n"
                "    time.sleep(120)\n"
                "print('up', flush=True)\n"
                "stuck_here()\n")
    monkeypatch.setattr(runner, "node_command",
                        lambda node, files, over=None: [sys.executable, "-c", stubborn])
    graph = GraphSpec("probe", "", (), (NodeSpec("stubborn", "x"),))
    out = io.StringIO()
    res = runner.run_graph(graph, out=out, install_signal_handlers=False,
                           should_stop=lambda: "[stubborn] up" in out.getvalue())
    text = out.getvalue()
    assert res.code == 1 and res.failed == ["stubborn"], text
    assert "node stubborn was killed (exit code -9)" in text
    # before the kill it was asked where it was stuck, and said so
    assert "in stuck_here" in text, text
