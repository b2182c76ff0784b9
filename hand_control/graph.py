"""Node graphs: one description per graph, read by ``hand-suite run`` and by ``ros2 launch``.

A graph is a YAML file ``config/graphs/<name>.yaml``::

    description: one line shown by `hand-suite run --list`
    params: [sim.yaml, controller.yaml]   # parameter file(s) under config/ (optional)
    nodes:
      - name: bag_player           # ROS node name
        executable: bag_player     # console script of hand_suite (setup.py)
        required: true             # when it exits, the whole graph stops (optional)
        remappings: {from: to}     # topic remappings (optional)
        parameters: {key: value}   # per-node overrides on top of the file (optional)

:func:`node_argv` turns a node into a command line for the runner; :func:`launch_description`
builds the same graph for ``ros2 launch`` (launch files call it), so the two cannot drift.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hand_capture.config import load_yaml
from hand_capture.dds import PROFILE_VARS, dds_environment
from hand_capture.errors import GraphError
from hand_capture.paths import config_dir

_NODE_KEYS = {"name", "executable", "required", "remappings", "parameters"}
_GRAPH_KEYS = {"description", "params", "nodes"}


@dataclass(frozen=True)
class NodeSpec:
    """One node of a graph."""

    name: str
    executable: str
    required: bool = False
    remappings: dict[str, str] = field(default_factory=dict)
    parameters: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class GraphSpec:
    """A named graph: its nodes and parameter file."""

    name: str
    description: str
    params_files: tuple[Path, ...]
    nodes: tuple[NodeSpec, ...]

    def node(self, name: str) -> NodeSpec:
        """The node called ``name``; GraphError lists the valid names."""
        for n in self.nodes:
            if n.name == name:
                return n
        raise GraphError(f"graph {self.name} has no node {name!r}; nodes: "
                         f"{[n.name for n in self.nodes]}")


def graphs_dir() -> Path:
    """``config/graphs``."""
    return config_dir() / "graphs"


def available_graphs() -> list[str]:
    """Names of every described graph."""
    return sorted(p.stem for p in graphs_dir().glob("*.yaml"))


def load_graph(name_or_path: str | Path) -> GraphSpec:
    """Read and validate a graph description by name (``replay``) or path.

    Raises:
        GraphError: unknown graph (lists the valid names) or malformed description.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = graphs_dir() / f"{name_or_path}.yaml"
    if not path.is_file():
        raise GraphError(f"unknown graph {str(name_or_path)!r}; available: {available_graphs()}")
    data = load_yaml(path) or {}
    if not isinstance(data, dict) or set(data) - _GRAPH_KEYS:
        raise GraphError(f"{path}: top-level keys must be among {sorted(_GRAPH_KEYS)}")
    nodes = []
    for i, nd in enumerate(data.get("nodes") or []):
        keys = set(nd) if isinstance(nd, dict) else set()
        if not isinstance(nd, dict) or keys - _NODE_KEYS or not {"name", "executable"} <= keys:
            raise GraphError(f"{path}: node #{i} needs 'name' and 'executable' and only keys "
                             f"{sorted(_NODE_KEYS)}")
        nodes.append(NodeSpec(name=str(nd["name"]), executable=str(nd["executable"]),
                              required=bool(nd.get("required", False)),
                              remappings=dict(nd.get("remappings") or {}),
                              parameters=dict(nd.get("parameters") or {})))
    if not nodes:
        raise GraphError(f"{path}: a graph needs at least one node")
    names = [n.name for n in nodes]
    if len(set(names)) != len(names):
        raise GraphError(f"{path}: node names must be unique, got {names}")
    params = data.get("params") or []
    params_files = tuple(config_dir() / f for f in ([params] if isinstance(params, str)
                                                    else params))
    for f in params_files:
        if not f.is_file():
            raise GraphError(f"{path}: parameter file {f} does not exist")
    return GraphSpec(path.stem, str(data.get("description", "")), params_files, tuple(nodes))


def format_value(value: Any) -> str:
    """A parameter value in ROS command-line syntax (``-p name:=value``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(format_value(v) for v in value) + "]"
    if isinstance(value, str):
        return value if value else "''"
    return repr(value)


def ros_args(node: NodeSpec, params_files: list[Path],
             overrides: dict[str, Any] | None = None) -> list[str]:
    """``--ros-args`` for one node: name, parameter files, per-node parameters, remappings.

    The per-node parameters are given for the node by name (``-p node:key:=value``): a bare
    ``-p key:=value`` would lose to an entry for the node in a parameter file."""
    args = ["--ros-args", "-r", f"__node:={node.name}"]
    for f in params_files:
        args += ["--params-file", str(f)]
    for key, value in {**node.parameters, **(overrides or {})}.items():
        args += ["-p", f"{node.name}:{key}:={format_value(value)}"]
    for src, dst in node.remappings.items():
        args += ["-r", f"{src}:={dst}"]
    return args


def launch_description(name: str) -> Any:
    """The graph as a ``launch.LaunchDescription`` for ``ros2 launch`` (workstations only).

    Launch argument ``params_file`` adds a parameter file on top of the graph's own. The nodes
    get loopback-only discovery unless the environment sets ``ROS_AUTOMATIC_DISCOVERY_RANGE``
    (:mod:`hand_capture.network`).
    """
    from launch.actions import (
        DeclareLaunchArgument,
        EmitEvent,
        RegisterEventHandler,
        SetEnvironmentVariable,
    )
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch.substitutions import EnvironmentVariable, LaunchConfiguration
    from launch_ros.actions import Node

    from hand_capture.network import DEFAULT_DISCOVERY_RANGE, DISCOVERY_RANGE_VAR
    from launch import LaunchDescription

    graph = load_graph(name)
    # the Fast DDS profile for large images (a profile the user set wins)
    dds_env = {k: v for k, v in dds_environment(os.environ).items() if k in PROFILE_VARS}
    actions: list[Any] = [SetEnvironmentVariable(
        DISCOVERY_RANGE_VAR,
        EnvironmentVariable(DISCOVERY_RANGE_VAR, default_value=DEFAULT_DISCOVERY_RANGE))]
    base: list[Any] = [str(f) for f in graph.params_files]
    if graph.params_files:
        # params_file defaults to the graph's last file; a user file given on the command
        # line is applied after the graph's own.
        actions.append(DeclareLaunchArgument(
            "params_file", default_value=str(graph.params_files[-1]),
            description="extra ROS parameter file applied to every node"))
        base.append(LaunchConfiguration("params_file"))
    for nd in graph.nodes:
        params: list[Any] = list(base)
        if nd.parameters:
            params.append(dict(nd.parameters))
        action = Node(package="hand_suite", executable=nd.executable, name=nd.name,
                      parameters=params, remappings=list(nd.remappings.items()),
                      additional_env=dds_env, output="screen", emulate_tty=True)
        actions.append(action)
        if nd.required:
            actions.append(RegisterEventHandler(OnProcessExit(
                target_action=action, on_exit=[EmitEvent(event=Shutdown(reason=nd.name))])))
    return LaunchDescription(actions)
