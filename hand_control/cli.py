"""The ``hand-suite`` command: run graphs, record and play bags, benchmarks, the main job.

    hand-suite run GRAPH [--params FILE] [-p node.param:=value ...] | run --list
    hand-suite record -o DIR [--storage mcap|sqlite3] [--all] TOPIC ...
    hand-suite play DIR [--rate R] [--loop] [--start S]
    hand-suite bag info DIR | bag check DIR | bag recover DIR [-o OUT]
    hand-suite bench NAME [--quick | --smoke] | bench --list
    hand-suite capture [-o DIR] [--clip C] [--seconds S] [--fps F] [--shape-seed N]
    hand-suite capture --rig studio6 [-o DIR] [--seconds S] [--fps F] [--objects box]
    hand-suite train touch|tracker|grasps|salient [ARGS]  fit the touch encodings / the
        tracker's forest / the grasp database and closing-phase models / the fingertip detector
    hand-suite calibrate rig BAG_OR_DIR -o config/rigs/NAME.yaml [--board 7x5:0.05:0.036]
    hand-suite track-multiview BAG -o OUT [--rig studio6] [--hands right] [--objects box]
    hand-suite mjcf OUT_DIR [--hand left] [--shape-seed N]   MuJoCo hand.xml + scenes
    hand-suite report BAG [-o DIR]       HTML report of a recorded bag
    hand-suite grasp OBJECT [--grip MODE] [-o OUT] [--play]   grasp synthesis (III.4)
    hand-suite physcap run ARCHIVE -o OUT [--workers N | --scheduler tcp://HOST:8786] [--quick]
    hand-suite physcap info PATH | sample DIR | replay RESULT   physics capture (Dask batch)
    hand-suite demo [--out DIR]          the README's main job
    hand-suite test [PYTEST ARGS]        lint + the test suite (what CI runs)
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import os
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from hand_capture.dds import dds_environment
from hand_capture.errors import HandSuiteError

BENCH_PACKAGES = ("hand_capture.bench", "hand_control.bench")


def _setup_environment() -> None:
    """Defaults for headless machines and a loopback-only ROS graph (overridable)."""
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "osmesa")
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    from hand_capture.network import apply_network_defaults

    apply_network_defaults()
    # the Fast DDS profile for large images, for this process and the ones it starts
    os.environ.update(dds_environment(os.environ))


def _parse_value(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def parse_overrides(items: list[str]) -> dict[str, dict[str, Any]]:
    """``["node.param:=value", ...]`` -> ``{node: {param: value}}``.

    Raises:
        HandSuiteError: an item is not of the form node.param:=value.
    """
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        key, sep, value = item.partition(":=")
        node, dot, name = key.partition(".")
        if not sep or not dot or not node or not name:
            raise HandSuiteError(f"bad override {item!r}; expected node.param:=value")
        out.setdefault(node, {})[name] = _parse_value(value)
    return out


def cmd_run(a: argparse.Namespace) -> int:
    from hand_control.graph import available_graphs, load_graph
    from hand_control.runner import run_graph

    if a.list or not a.graph:
        for name in available_graphs():
            print(f"{name:12s} {load_graph(name).description}")
        return 0
    graph = load_graph(a.graph)
    extra = [Path(p) for p in a.params]
    return run_graph(graph, extra, parse_overrides(a.p)).code


def _node_args(params: dict[str, Any]) -> list[str]:
    from hand_control.graph import format_value

    args = ["--ros-args"]
    for k, v in params.items():
        args += ["-p", f"{k}:={format_value(v)}"]
    return args


def cmd_record(a: argparse.Namespace) -> int:
    from hand_capture.nodes import recorder

    if not a.topics and not a.all:
        raise HandSuiteError("name the topics to record, or --all")
    params = {"output": a.output, "storage": a.storage, "all_topics": a.all}
    if a.topics:
        params["topics"] = list(a.topics)
    return recorder.main(["hand-suite-record", *_node_args(params)])


def cmd_play(a: argparse.Namespace) -> int:
    from hand_capture.nodes import player

    params = {"bag": a.bag, "rate": float(a.rate), "loop": a.loop, "start": float(a.start),
              "wait_for_subscribers": a.wait_for_subscribers}
    return player.main(["hand-suite-play", *_node_args(params)])


def cmd_bag(a: argparse.Namespace) -> int:
    from hand_capture.bag import BagReader, recover_bag

    if a.action == "recover":
        res = recover_bag(a.bag, a.output)
        print(res.describe())
        return 0
    with BagReader(a.bag) as r:  # refuses a bag whose CRCs do not match, naming the part
        counts: dict[str, int] = {}
        for m in r.messages():
            counts[m.topic] = counts.get(m.topic, 0) + 1
            if a.action == "check":
                r.check(m)  # every payload decodes
        if a.action == "check":
            crc = "CRCs and payloads" if r.crc_verified else "payloads (no CRCs in this bag)"
            print(f"{a.bag}: ok ({sum(counts.values())} messages, {crc} checked)")
            return 0
        print(f"bag:      {a.bag}\nduration: {r.duration_s:.3f} s\nmessages: {r.message_count}")
        for topic, msgtype in sorted(r.topics.items()):
            print(f"  {topic:40s} {msgtype:36s} {counts.get(topic, 0)}")
    return 0


def available_benches() -> dict[str, str]:
    """Benchmark name -> module (every module with a ``run`` in the bench packages)."""
    found = {}
    for pkg_name in BENCH_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        for info in pkgutil.iter_modules(pkg.__path__):
            if not info.name.startswith("_"):
                found[info.name] = f"{pkg_name}.{info.name}"
    return found


def cmd_bench(a: argparse.Namespace) -> int:
    from hand_capture.bench import json_line

    benches = available_benches()
    if a.list or not a.name:
        print("\n".join(sorted(benches)))
        return 0
    if a.name not in benches:
        raise HandSuiteError(f"unknown benchmark {a.name!r}; available: {sorted(benches)}")
    module = importlib.import_module(benches[a.name])
    kwargs: dict[str, bool] = {"quick": bool(a.quick or a.smoke)}
    if a.smoke and "smoke" in inspect.signature(module.run).parameters:
        kwargs["smoke"] = True  # else its --quick run is its smallest
    figures = module.run(**kwargs)
    smoke = {"smoke": True} if a.smoke else {}
    print(json_line({"bench": a.name, "quick": kwargs["quick"], **smoke, **figures}))
    return 0


def cmd_capture(a: argparse.Namespace) -> int:
    from hand_capture.cameras.synthetic import SyntheticCameraConfig
    from hand_capture.nodes.capture import SAMPLE_CAPTURE, write_capture

    if a.rig:
        return _capture_rig(a)
    if a.params:  # the synthetic_camera section (and /**) of a ROS parameter file
        from dataclasses import replace

        from hand_capture.config import load_node_params

        cfg = replace(load_node_params(SyntheticCameraConfig, a.params, "synthetic_camera"),
                      fps=a.fps, shape_seed=a.shape_seed, noise_seed=a.noise_seed,
                      render_color=True)
    else:
        cfg = SyntheticCameraConfig(clip=a.clip or "grasp", fps=a.fps, shape_seed=a.shape_seed,
                                    noise_seed=a.noise_seed)
    res = write_capture(a.output or SAMPLE_CAPTURE, cfg, seconds=a.seconds, overwrite=True)
    print(f"wrote {res.frames} frames ({res.messages} messages, {res.size_bytes / 1e6:.2f} MB) "
          f"to {res.path}")
    return 0


def _capture_rig(a: argparse.Namespace) -> int:
    from hand_capture.multiview.studio import StudioNoise
    from hand_capture.nodes.rig_capture import SAMPLE_RIG_CAPTURE, write_rig_capture

    out = Path(a.output) if a.output else SAMPLE_RIG_CAPTURE
    objects: list[object] = [o for o in a.objects.split(",") if o]
    qpos = None
    if a.scenario:  # physically consistent motion: the scenario simulated, then rendered
        from hand_control.sim.lockstep import record_motion
        from hand_control.sim.scenario import load_scenario

        objects, qpos = record_motion(load_scenario(a.scenario), a.fps, a.seconds)
    poses = None
    if a.pose_file or a.clip:
        import numpy as np

        from hand_capture.cameras.motion import load_motion

        clip = load_motion(a.clip or "", a.pose_file, rate=a.pose_file_rate, loop=True)
        poses = clip.sample_many(np.arange(int(round(a.seconds * a.fps))) / a.fps)
        if not a.pose_file:  # a clip is a hand in front of a camera: put that camera above
            from hand_capture.cameras.transforms import pose_in_world  # the studio's table
            from hand_capture.multiview.rig import look_at

            eye, centre = np.array([0.0, 0.0, 0.55]), np.array([0.0, 0.0, 0.12])
            R_wc = look_at(eye, centre, up=(1.0, 0.0, 0.0))
            poses = np.array([pose_in_world(q, R_wc, eye) for q in poses])
    res = write_rig_capture(out, a.rig, seconds=a.seconds, fps=a.fps, objects=objects,
                            qpos=qpos, poses=poses,
                            noise=StudioNoise(sensor_sigma=a.sensor_noise, seed=a.noise_seed),
                            noise_seed=a.noise_seed, two_hands=a.two_hands,
                            surface_seed=None if a.heldout_surface < 0 else a.heldout_surface,
                            overwrite=a.output is None or a.overwrite)
    print(f"wrote {res.frames} groups of {res.cameras} cameras ({res.messages} messages, "
          f"{res.size_bytes / 1e6:.2f} MB) to {res.path}")
    return 0


TRAINERS = {"touch": "hand_capture.touch.train", "tracker": "hand_capture.tracking.train",
            "grasps": "hand_control.grasp.train", "salient": "hand_capture.multiview.salient"}


def cmd_train(a: argparse.Namespace) -> int:
    if a.what not in TRAINERS:
        raise HandSuiteError(f"nothing to train called {a.what!r}; valid: {sorted(TRAINERS)}")
    return int(importlib.import_module(TRAINERS[a.what]).main(a.train_args) or 0)


def cmd_mjcf(a: argparse.Namespace) -> int:
    from hand_capture.model import mjcf

    return mjcf.main(a.mjcf_args)


def cmd_report(a: argparse.Namespace) -> int:
    from hand_control.demo import teleop_scenario
    from hand_control.report import build_report
    from hand_control.report.frames import sim_frame_renderer

    out = Path(a.output) if a.output else Path(a.bag).with_name(Path(a.bag).name + "_report")
    res = build_report(a.bag, out, frames_fn=sim_frame_renderer(a.scenario or teleop_scenario()))
    print(f"report: {res.html} ({len(res.figures)} figures)")
    for key, value in sorted(res.numbers.items()):
        print(f"  {key:32s} {value:.4g}")
    return 0


def cmd_demo(a: argparse.Namespace) -> int:
    from hand_control.demo import teleop_demo

    return teleop_demo(Path(a.out))


def cmd_calibrate(a: argparse.Namespace) -> int:
    from hand_capture.bench import print_table
    from hand_capture.multiview.calibrate import calibrate_rig
    from hand_capture.multiview.charuco import parse_board
    from hand_capture.multiview.rig import save_rig
    from hand_capture.multiview.views import load_views

    spec = parse_board(a.board)
    images = load_views(a.input, a.cameras.split(",") if a.cameras else None)
    name = a.name or Path(a.output).stem
    res = calibrate_rig(images, spec, name=name, reference_view=a.reference_view)
    print_table(f"rig {name}: {len(res.rig)} cameras, {len(res.board_poses)} board views",
                ["camera", "views", "reprojection RMS [px]", "fx [px]", "fy [px]", "cx", "cy"],
                [[c.name, res.observations[c.name], res.reproj_px[c.name], c.intrinsics.fx,
                  c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy] for c in res.rig.cameras])
    out = save_rig(res.rig, a.output, header=[
        f"written by: hand-suite calibrate rig {a.input} --board {a.board}",
        f"world frame: the board at view {a.reference_view}, z up when it lies face up"])
    print(f"\nwrote {out}")
    return 0


def cmd_track_multiview(a: argparse.Namespace) -> int:
    from hand_capture.bench import print_table
    from hand_capture.multiview.lo import LOConfig
    from hand_capture.nodes.multiview_tracker import track_bag

    res = track_bag(a.bag, a.output, rig=a.rig, hands=a.hands, objects=a.objects,
                    lo_config=LOConfig(iterations=a.iterations), max_groups=a.max_groups,
                    overwrite=a.overwrite, detector=a.detector,
                    hull_recovery=not a.no_hull)
    err = "no truth in the bag" if res.joint_err_mm is None else f"{res.joint_err_mm:.2f}"
    print_table(f"track-multiview {a.bag} -> {res.output}",
                ["groups", "tracked", "rejected", "s/group", "joint err mm", "lost part-frames"],
                [[res.groups, res.tracked, sum(res.rejected.values()), res.seconds_per_group,
                  err, res.lost_frames]])
    return 0


TEST_WORKERS_MAX = 4  # pytest-xdist workers at most: every graph test starts 3-6 processes


def xdist_options(pytest_args: list[str], cpus: int | None) -> list[str]:
    """The pytest-xdist options the test command adds: one worker per CPU, at most
    ``TEST_WORKERS_MAX``, tests handed out one by one (``--dist load``: 567 s on 2 cores
    against 597 s with each file kept on one worker, and 921 s in one process, one machine,
    the same day). Nothing is added when the arguments choose themselves (``-n``,
    ``--numprocesses``, ``-p no:xdist``) or on a single CPU."""
    chosen = any(x == "no:xdist" or x.startswith(("-n", "--numpro")) for x in pytest_args)
    n = min(cpus or 1, TEST_WORKERS_MAX)
    return [] if chosen or n < 2 else ["-n", str(n), "--dist", "load"]


def cmd_test(a: argparse.Namespace) -> int:
    root = Path(__file__).resolve().parents[1]
    venv_bin = Path(sys.executable).parent
    ruff = shutil.which("ruff", path=str(venv_bin)) or "ruff"
    print("[test] ruff check", flush=True)
    if subprocess.call([ruff, "check", str(root)], cwd=root) != 0:
        return 1
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    args = [*xdist_options(a.pytest_args, cpus), *a.pytest_args]
    print("[test] pytest " + " ".join(args), flush=True)
    code = subprocess.call([sys.executable, "-m", "pytest", "-q", *args], cwd=root)
    return 1 if code == 5 else code  # 5 = no test collected: never a silent pass


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hand-suite", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="start a node graph")
    r.add_argument("graph", nargs="?")
    r.add_argument("--list", action="store_true", help="list the graphs")
    r.add_argument("--params", action="append", default=[], metavar="FILE",
                   help="extra ROS parameter file (after the graph's own)")
    r.add_argument("-p", action="append", default=[], metavar="NODE.PARAM:=VALUE")
    r.set_defaults(func=cmd_run)

    rec = sub.add_parser("record", help="record topics into a bag")
    rec.add_argument("-o", "--output", required=True)
    rec.add_argument("--storage", default="mcap", choices=["mcap", "sqlite3"])
    rec.add_argument("--all", action="store_true", help="record every topic")
    rec.add_argument("topics", nargs="*")
    rec.set_defaults(func=cmd_record)

    pl = sub.add_parser("play", help="replay a bag")
    pl.add_argument("bag")
    pl.add_argument("--rate", type=float, default=1.0)
    pl.add_argument("--loop", action="store_true")
    pl.add_argument("--start", type=float, default=0.0, help="seconds into the bag")
    pl.add_argument("--wait-for-subscribers", action="store_true")
    pl.set_defaults(func=cmd_play)

    b = sub.add_parser("bag", help="inspect or recover a bag")
    b.add_argument("action", choices=["info", "check", "recover"])
    b.add_argument("bag")
    b.add_argument("-o", "--output", default=None, help="recover: output bag")
    b.set_defaults(func=cmd_bag)

    be = sub.add_parser("bench", help="run a benchmark")
    be.add_argument("name", nargs="?")
    be.add_argument("--quick", action="store_true")
    be.add_argument("--smoke", action="store_true",
                    help="the smallest run through the same code (the test suite's check); "
                         "--quick for a bench without a smaller mode")
    be.add_argument("--list", action="store_true")
    be.set_defaults(func=cmd_bench)

    cp = sub.add_parser("capture", help="synthetic RGB-D capture with ground truth into a bag")
    cp.add_argument("-o", "--output", default=None, help="bag (default data/sample_capture)")
    cp.add_argument("--clip", default=None, help="motion clip (default grasp); with --rig "
                    "the clip is seen by a camera 0.43 m above the table, looking down")
    cp.add_argument("--params", default=None,
                    help="camera from a parameter file's synthetic_camera section (e.g. "
                    "config/teleop.yaml: the teleop performance); replaces --clip")
    cp.add_argument("--seconds", type=float, default=3.0)
    cp.add_argument("--fps", type=float, default=12.0)
    cp.add_argument("--shape-seed", type=int, default=-1, help="-1 = default hand shape")
    cp.add_argument("--noise-seed", type=int, default=0)
    cp.add_argument("--rig", default="", help="multi-view: render this rig's cameras "
                    "(config/rigs/NAME.yaml) in the studio (default output "
                    "data/sample_rig_capture)")
    cp.add_argument("--objects", default="box", help="--rig: objects on the table (comma list)")
    cp.add_argument("--sensor-noise", type=float, default=2.0,
                    help="--rig: colour sensor noise [grey levels]; 0 compresses far better")
    cp.add_argument("--overwrite", action="store_true", help="--rig: replace -o if it exists")
    cp.add_argument("--two-hands", action="store_true", help="--rig: a left hand too")
    cp.add_argument("--heldout-surface", type=int, default=-1, metavar="SEED",
                    help="--rig: the right hand as a held-out-family subject (other shapes, "
                    "forearm, sleeve) drawn from SEED; -1 = the MJCF hand")
    cp.add_argument("--scenario", default="", help="--rig: motion of a simulated scenario "
                    "(config/scenarios/NAME.yaml) instead of the studio's performance")
    cp.add_argument("--pose-file", default="", help="--rig: world-frame hand poses (CSV / "
                    "NPZ, 27 values per row) instead of the studio's performance (a --clip "
                    "is a camera-frame motion instead)")
    cp.add_argument("--pose-file-rate", type=float, default=30.0,
                    help="--rig: rate of a pose file without a time column [Hz]")
    cp.set_defaults(func=cmd_capture)

    tr = sub.add_parser("train",
                        help="train a learned component (touch, tracker, grasps, salient)")
    tr.add_argument("what")
    tr.add_argument("train_args", nargs=argparse.REMAINDER)
    tr.set_defaults(func=cmd_train)

    ca = sub.add_parser("calibrate", help="calibrate a multi-view camera rig (ChArUco)")
    ca.add_argument("what", choices=["rig"])
    ca.add_argument("input", help="bag with <cam>/color/image_raw topics, or a folder of "
                    "<cam>/<view>.png images")
    ca.add_argument("-o", "--output", required=True, help="rig file to write")
    ca.add_argument("--board", default="7x5:0.05:0.036:DICT_4X4_50",
                    help="ChArUco board: SQUARESxSQUARES:SQUARE_M:MARKER_M[:DICTIONARY]")
    ca.add_argument("--cameras", default="", help="comma-separated cameras (default: all)")
    ca.add_argument("--reference-view", type=int, default=0,
                    help="view whose board (lying face up) defines the world frame")
    ca.add_argument("--name", default="", help="rig name (default: the output's stem)")
    ca.set_defaults(func=cmd_calibrate)

    tm = sub.add_parser("track-multiview", help="track hands and objects in a multi-view bag")
    tm.add_argument("bag", help="bag with <cam>/color/image_raw topics of the rig's cameras")
    tm.add_argument("-o", "--output", required=True, help="bag to write the estimates to")
    tm.add_argument("--rig", default="studio6", help="rig name or rig file")
    tm.add_argument("--hands", default="right", help="right, left or right,left")
    tm.add_argument("--objects", default="box", help="comma list of object kinds ('' none)")
    tm.add_argument("--iterations", type=int, default=15, help="outer iterations a frame")
    tm.add_argument("--max-groups", type=int, default=None, help="track only the first N")
    tm.add_argument("--overwrite", action="store_true", help="replace -o if it exists")
    tm.add_argument("--detector", default="learned", choices=["learned", "none"],
                    help="salient points from the learned fingertip detector, or none")
    tm.add_argument("--no-hull", action="store_true",
                    help="search for a lost hand around its last pose only")
    tm.set_defaults(func=cmd_track_multiview)

    mj = sub.add_parser("mjcf", help="write the MuJoCo hand.xml and scenes",
                        add_help=False)
    mj.add_argument("mjcf_args", nargs=argparse.REMAINDER)
    mj.set_defaults(func=cmd_mjcf)

    rp = sub.add_parser("report", help="HTML report of a recorded bag")
    rp.add_argument("bag")
    rp.add_argument("-o", "--output", default=None, help="report folder (BAG_report)")
    rp.add_argument("--scenario", default=None,
                    help="scenario the sim ran, for the rendered frames (default: teleop's)")
    rp.set_defaults(func=cmd_report)

    from hand_control.physcap.cli import add_parser as add_physcap

    add_physcap(sub)

    d = sub.add_parser("demo", help="the main job (README)")
    d.add_argument("--out", default="out/demo")
    d.set_defaults(func=cmd_demo)

    from hand_control.grasp.command import add_parser as add_grasp_parser

    add_grasp_parser(sub)

    t = sub.add_parser("test", help="lint and run the tests")
    t.add_argument("pytest_args", nargs=argparse.REMAINDER)
    t.set_defaults(func=cmd_test)
    return p


_PASSED_ON = {"test": "pytest_args", "mjcf": "mjcf_args", "train": "train_args"}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line, parsed. The commands that hand their arguments on (``test`` to pytest,
    ``mjcf`` and ``train`` to their tools) take options first among them too (``test -n 0``,
    ``test --durations=30 test/test_sim.py``), which ``argparse.REMAINDER`` alone refuses;
    every other command refuses an argument it does not know."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    dest = _PASSED_ON.get(args.command)
    if extra and dest is None:
        parser.error("unrecognized arguments: " + " ".join(extra))
    if dest is not None:
        setattr(args, dest, [*extra, *getattr(args, dest)])
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hand-suite`` console script."""
    _setup_environment()
    args = parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except HandSuiteError as e:
        print(f"hand-suite {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
