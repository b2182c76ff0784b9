"""Physics capture over an archive: loading and validating captures (npz files and bags),
writing results (npz + bag the player and the report read), and the batch on a Dask local
cluster of two worker processes giving the same results as a serial run (issue 16)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from hand_capture.bag import BagReader, BagWriter, default_typestore
from hand_capture.model.joints import rest_pose
from hand_control.physcap.archive import (
    ArchiveConfig,
    CorruptCaptureError,
    IncompleteCaptureError,
    ObjectProperties,
    list_archive,
    load_entry,
    read_capture_bag,
)
from hand_control.physcap.capture import (
    Capture,
    CapturedObject,
    PhysCapConfig,
    PhysCapResult,
    save_capture_npz,
)
from hand_control.physcap.output import (
    OUTPUT_TOPICS,
    read_result,
    results_equal,
    write_result,
)

T0_NS = 1_700_000_000_000_000_000
BOX = {"kind": "box", "size": [0.02, 0.02, 0.02], "mass": 0.15, "friction": 0.8}


def _motion(n: int = 12, rate: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times (n,), hand poses (n, 27), object poses (n, 7)): a hand lifting a box."""
    t = np.arange(n) / rate
    q = np.tile(rest_pose(), (n, 1))
    q[:, 0:3] = [0.05, 0.0, 0.12]
    q[:, 2] += np.linspace(0.0, 0.05, n)
    q[:, 8] = np.linspace(0.2, 0.9, n)
    op = np.zeros((n, 7))
    op[:, 0], op[:, 2], op[:, 3] = 0.12, 0.02 + np.linspace(0.0, 0.05, n), 1.0
    return t, q, op


def _write_bag(path: Path, t: np.ndarray, q: np.ndarray, op: np.ndarray | None,
               hand_topic: str = "/hand/pose", obj_topic: str = "/object/pose_truth",
               frame: str = "world", custom: dict | None = None, obj_every: int = 1,
               left: np.ndarray | None = None, lost: tuple[int, ...] = ()) -> Path:
    """A capture bag as the multi-view tracker / the studio record it."""
    from hand_capture.posemsg import fill_pose_msg

    store = default_typestore()
    T = store.types
    w = BagWriter(path)
    if custom:  # rosbag2 custom data in metadata.yaml
        w._writer.set_custom_data(*next(iter(custom.items())))
    w.add_topic(hand_topic, "hand_msgs/msg/HandPose")
    if op is not None:
        w.add_topic(obj_topic, "geometry_msgs/msg/PoseStamped")
    pose = T["geometry_msgs/msg/Pose"]
    point, quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    try:
        for k, tk in enumerate(t):
            t_ns = T0_NS + int(round(tk * 1e9))
            header = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9,
                                                       nanosec=t_ns % 10**9),
                frame_id=frame)
            hp = T["hand_msgs/msg/HandPose"](
                header=header, handedness=0, joint_names=[], positions=np.zeros(0),
                wrist_pose=pose(position=point(x=0.0, y=0.0, z=0.0),
                                orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0)),
                confidence=1.0, status=1, source="test")
            for side, qs in (("left", left), ("right", q)):
                if qs is None:
                    continue
                fill_pose_msg(hp, qs[k], side=side,
                              status="lost" if k in lost else "tracking")
                hp.positions = np.asarray(hp.positions)
                w.write(hand_topic, t_ns,
                        bytes(store.serialize_cdr(hp, "hand_msgs/msg/HandPose")))
            if op is not None and k % obj_every == 0:
                p = op[k]
                ps = T["geometry_msgs/msg/PoseStamped"](header=header, pose=pose(
                    position=point(x=p[0], y=p[1], z=p[2]),
                    orientation=quat(x=p[4], y=p[5], z=p[6], w=p[3])))
                w.write(obj_topic, t_ns,
                        bytes(store.serialize_cdr(ps, "geometry_msgs/msg/PoseStamped")))
    finally:
        w.close()
    return path


def _sidecar(bag: Path, props: dict) -> None:
    name = bag.stem if bag.is_file() else bag.name
    (bag.parent / f"{name}.object.yaml").write_text(yaml.safe_dump(props))


def _npz_capture(path: Path, name: str, n: int = 12) -> Capture:
    t, q, op = _motion(n)
    c = Capture(name, t, q, op, CapturedObject("box", (0.02, 0.02, 0.02), 0.15, 0.8))
    save_capture_npz(c, path)
    return c


def _corrupt_middle(file: Path) -> None:
    data = bytearray(file.read_bytes())
    for i in range(len(data) // 2, len(data) // 2 + 16):
        data[i] ^= 0xFF
    file.write_bytes(bytes(data))


# ---------------------------------------------------------------------------------- archive


def test_bag_capture_reads_hand_object_and_sidecar_object(tmp_path):
    t, q, op = _motion()
    bag = _write_bag(tmp_path / "lift", t, q, op)
    _sidecar(bag, BOX)
    cap, source = read_capture_bag(bag)
    assert source == "sidecar" and cap.name == "lift"
    np.testing.assert_allclose(cap.times, t, atol=1e-9)
    np.testing.assert_allclose(cap.hand_q, q, atol=1e-6)
    np.testing.assert_allclose(cap.object_pose, op, atol=1e-9)
    assert cap.obj == CapturedObject("box", (0.02, 0.02, 0.02), 0.15, 0.8)


def test_bag_with_two_hands_gives_the_chosen_one(tmp_path):
    t, q, op = _motion()
    left = q.copy()
    left[:, 1] += 0.3
    bag = _write_bag(tmp_path / "two", t, q, op, left=left, hand_topic="/hand/pose_truth")
    _sidecar(bag, BOX)
    right, _ = read_capture_bag(bag)
    np.testing.assert_allclose(right.hand_q, q, atol=1e-6)
    other, _ = read_capture_bag(bag, config=ArchiveConfig(hand="left"))
    np.testing.assert_allclose(other.hand_q, left, atol=1e-6)


def test_frames_of_a_lost_tracker_are_dropped(tmp_path):
    t, q, op = _motion()
    bag = _write_bag(tmp_path / "lost", t, q, op, lost=(4, 5))
    _sidecar(bag, BOX)
    cap, _ = read_capture_bag(bag)
    keep = [k for k in range(len(t)) if k not in (4, 5)]
    np.testing.assert_allclose(cap.times, t[keep], atol=1e-9)
    np.testing.assert_allclose(cap.hand_q, q[keep], atol=1e-6)


def test_bag_object_from_metadata_and_object_poses_interpolated(tmp_path):
    t, q, op = _motion(13)
    # object poses at half the hand's rate (frames 0, 2, ..., 12): interpolated at the
    # hand's stamps (the motion is linear, so exactly)
    bag = _write_bag(tmp_path / "meta", t, q, op, obj_every=2,
                     custom={"physcap_object": yaml.safe_dump(
                         {"kind": "ball", "size": [0.03], "mass": 0.1, "friction": 0.5})})
    cap, source = read_capture_bag(bag, ObjectProperties(kind="box", size=(0.1, 0.1, 0.1)))
    assert source == "metadata" and cap.obj == CapturedObject("sphere", (0.03,), 0.1, 0.5)
    assert cap.n_frames == 13
    np.testing.assert_allclose(cap.object_pose, op, atol=1e-9)


def test_hand_only_bag_uses_the_given_object_pose_and_camera(tmp_path):
    """The depth tracker's bags: hand/pose in the camera frame, no object poses."""
    from hand_capture.cameras.transforms import pose_in_camera
    from hand_capture.model.joints import quat_wxyz_to_matrix

    t, q, op = _motion(12)
    cam = np.array([0.0, 0.0, 0.6, 0.0, 1.0, 0.0, 0.0])  # looking down (180 deg about x)
    R = quat_wxyz_to_matrix(cam[3:7])
    q_cam = np.array([pose_in_camera(x, R, cam[:3]) for x in q])
    bag = _write_bag(tmp_path / "depth", t, q_cam, None, frame="camera_depth_optical_frame")
    # no object poses, no object: incomplete, named
    e = list_archive(tmp_path)[0]
    assert e.status == "incomplete" and "no object properties" in e.reason
    props = ObjectProperties(**{**BOX, "size": tuple(BOX["size"])},
                             pose=tuple(op[0]), camera_pose=tuple(cam))
    cap, source = read_capture_bag(bag, props, ArchiveConfig(touch_distance=0.2))
    assert source == "default"
    np.testing.assert_allclose(cap.hand_q, q, atol=1e-6)  # back in the world frame
    np.testing.assert_allclose(cap.object_pose[0], op[0], atol=1e-9)  # at rest first
    # after the hand arrived, the object moves with the hand root (it lifts with it)
    assert cap.object_pose[-1, 2] - cap.object_pose[0, 2] == pytest.approx(
        q[-1, 2] - q[0, 2], abs=0.02)
    without_pose = replace(props, pose=())
    with pytest.raises(IncompleteCaptureError, match="no object poses"):
        read_capture_bag(bag, without_pose)


def test_archive_names_corrupt_and_incomplete_captures(tmp_path):
    arch = tmp_path / "archive"
    arch.mkdir()
    t, q, op = _motion(12)
    _npz_capture(arch / "good_npz.npz", "good_npz")
    good = _write_bag(arch / "good_bag", t, q, op)
    _sidecar(good, BOX)
    crc = _write_bag(arch / "crc_bag", t, q, op)  # a damaged chunk: CRC mismatch
    _sidecar(crc, BOX)
    _corrupt_middle(next(crc.glob("*.mcap")))
    cut = _write_bag(arch / "cut_bag", t, q, op)  # truncated storage
    _sidecar(cut, BOX)
    f = next(cut.glob("*.mcap"))
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    no_obj = _write_bag(arch / "no_object", t, q, None)
    _sidecar(no_obj, BOX)
    short = _write_bag(arch / "short", t[:3], q[:3], op[:3])
    _sidecar(short, BOX)
    nan_q = q.copy()
    nan_q[5, 9] = np.nan
    nan_bag = _write_bag(arch / "nan_bag", t, nan_q, op)
    _sidecar(nan_bag, BOX)
    # an npz with the capture's keys but a NaN object pose (save_capture_npz refuses it)
    np.savez(arch / "nan_npz.npz", name=np.array("nan_npz"), times=t, hand_q=q,
             object_pose=np.where(np.arange(12)[:, None] == 4, np.nan, op),
             obj_kind=np.array("box"), obj_size=np.array([0.02] * 3),
             obj_mass=np.array(0.2), obj_friction=np.array(0.7))
    (arch / "zip_npz.npz").write_bytes((arch / "good_npz.npz").read_bytes()[:200])
    (arch / "notes.txt").write_text("not a capture")
    # a bag as one MCAP file (as the mcap tools write them)
    single = _write_bag(tmp_path / "single_src", t, q, op)
    (arch / "single.mcap").write_bytes(next(single.glob("*.mcap")).read_bytes())
    _sidecar(arch / "single.mcap", BOX)

    entries = {e.name: e for e in list_archive(arch)}
    assert sorted(entries) == ["crc_bag", "cut_bag", "good_bag", "good_npz", "nan_bag",
                               "nan_npz", "no_object", "short", "single", "zip_npz"]
    status = {n: e.status for n, e in entries.items()}
    assert status == {"good_npz": "ok", "good_bag": "ok", "single": "ok", "crc_bag": "corrupt",
                      "cut_bag": "corrupt", "zip_npz": "corrupt", "no_object": "incomplete",
                      "short": "incomplete", "nan_bag": "incomplete", "nan_npz": "incomplete"}
    assert "CRC" in entries["crc_bag"].reason
    assert "no object poses" in entries["no_object"].reason
    assert "3 frames" in entries["short"].reason
    assert "NaN" in entries["nan_bag"].reason or "non-finite" in entries["nan_bag"].reason
    assert "non-finite" in entries["nan_npz"].reason
    assert entries["good_bag"].frames == 12 and entries["good_bag"].object_source == "sidecar"
    # loading a bad entry raises the named error
    with pytest.raises(CorruptCaptureError, match="crc_bag"):
        load_entry(entries["crc_bag"])
    with pytest.raises(IncompleteCaptureError, match="short"):
        load_entry(entries["short"])


# ----------------------------------------------------------------------------------- output


def _fake_result(name: str = "lift", n: int = 12) -> PhysCapResult:
    rng = np.random.default_rng(3)
    t, q, op = _motion(n)
    return PhysCapResult(
        name=name, times=t, hand_q=q + rng.normal(0, 1e-3, q.shape), object_pose=op,
        reference_q=q, reference_object=op, targets=q[1:], object_targets=op[1:],
        virtual_forces=rng.normal(size=(n - 1, 6)), costs=rng.random(n),
        frame_seconds=rng.random(n - 1), success=True, reached_goal=True, dropped=False,
        final_error_m=0.004, config=PhysCapConfig(n_samples=8, n_keep=4, seed=5),
        obj=CapturedObject("cylinder", (0.02, 0.05), 0.3, 0.6),
        extras={"potential_contacts_mean": 2.5, "per_step": np.arange(3.0)})


def test_result_round_trip_npz_bag_and_back_into_an_archive(tmp_path):
    res = _fake_result()
    files = write_result(res, tmp_path / "out" / "lift")
    back = read_result(files.root)
    assert results_equal(res, back) == []
    np.testing.assert_array_equal(back.frame_seconds, res.frame_seconds)
    assert back.extras["potential_contacts_mean"] == 2.5
    np.testing.assert_array_equal(back.extras["per_step"], np.arange(3.0))
    with BagReader(files.bag) as r:
        counts: dict[str, int] = {}
        for m in r.messages():
            r.check(m)
            counts[m.topic] = counts.get(m.topic, 0) + 1
    assert set(counts) == set(OUTPUT_TOPICS)
    assert counts["/hand/pose"] == 12 and counts["/control/joint_command"] == 11
    # the result bag + its sidecar is itself a capture of the simulated motion
    cap, source = read_capture_bag(files.bag)
    assert source == "sidecar" and cap.obj == res.obj
    np.testing.assert_allclose(cap.hand_q, res.hand_q, atol=1e-6)
    np.testing.assert_allclose(cap.object_pose, res.object_pose, atol=1e-9)
    # a result bag is never overwritten
    from hand_capture.errors import BagError

    with pytest.raises(BagError, match="exists"):
        write_result(res, files.root)


def test_result_bag_feeds_the_report(tmp_path):
    from hand_control.report import build_report

    files = write_result(_fake_result(), tmp_path / "lift")
    rep = build_report(files.bag, tmp_path / "report")
    assert "object_max_lift_mm" in rep.numbers and "object_err_mean_mm" in rep.numbers
    assert rep.numbers["object_max_lift_mm"] == pytest.approx(50.0, abs=0.5)


def test_capture_bag_round_trip(tmp_path):
    from hand_control.physcap.output import write_capture_bag

    c = _npz_capture(tmp_path / "c.npz", "c")
    bag = write_capture_bag(c, tmp_path / "arch" / "take")
    assert (tmp_path / "arch" / "take.object.yaml").is_file()
    (entry,) = list_archive(tmp_path / "arch")
    assert entry.ok and entry.object_source == "sidecar"
    back = load_entry(entry)
    assert back.name == "take" and back.obj == c.obj
    np.testing.assert_allclose(back.times, c.times, atol=1e-9)
    np.testing.assert_allclose(back.hand_q, c.hand_q, atol=1e-6)
    np.testing.assert_allclose(back.object_pose, c.object_pose, atol=1e-9)
    from hand_capture.errors import BagError

    with pytest.raises(BagError, match="exists"):
        write_capture_bag(c, bag)
    # one capture (a bag or a file) is an archive of one
    assert [e.name for e in list_archive(bag)] == ["take"]
    assert [e.name for e in list_archive(tmp_path / "c.npz")] == ["c"]


def test_read_result_refuses_other_files(tmp_path):
    from hand_capture.errors import InputError

    _npz_capture(tmp_path / "cap.npz", "cap")
    with pytest.raises(InputError, match="not a physcap result"):
        read_result(tmp_path / "cap.npz")
    with pytest.raises(InputError, match="no such result"):
        read_result(tmp_path / "missing.npz")


# ------------------------------------------------------------------------------------ batch

#: a tiny optimisation (a few samples per step) so a batch runs in seconds
TINY = PhysCapConfig(n_samples=8, n_keep=4, seed=11)


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """Three short captures of the lift_box episode (npz + a bag), a corrupt one, an
    incomplete one and one whose optimisation fails (its mesh file does not exist)."""
    from hand_control.physcap.synth import scenario_capture
    from hand_control.sim.scenario import load_scenario

    arch = tmp_path_factory.mktemp("physcap") / "archive"
    arch.mkdir()
    full = scenario_capture(load_scenario("lift_box"))

    def part(name: str, start: int, n: int = 7, obj: CapturedObject | None = None) -> Capture:
        s = slice(start, start + n)
        return Capture(name, full.times[s] - full.times[start], full.hand_q[s],
                       full.object_pose[s], obj or full.obj)

    for name, start in (("take_a", 0), ("take_b", 12)):
        save_capture_npz(part(name, start), arch / f"{name}.npz")
    c = part("take_c", 20)
    bag = _write_bag(arch / "take_c", c.times, c.hand_q, c.object_pose)
    o = c.obj
    _sidecar(bag, {"kind": o.kind, "size": list(o.size), "mass": o.mass,
                   "friction": o.friction})
    save_capture_npz(part("no_mesh", 0, obj=CapturedObject("mesh", (), 0.2, 0.7,
                                                           str(arch / "missing.obj"))),
                     arch / "no_mesh.npz")
    (arch / "broken.npz").write_bytes((arch / "take_a.npz").read_bytes()[:300])
    _write_bag(arch / "hand_only", c.times, c.hand_q, None)
    _sidecar(arch / "hand_only", BOX)
    return arch


def _check_batch(res, out: Path) -> None:
    status = {o.name: o.status for o in res.outcomes}
    assert status == {"broken": "corrupt", "hand_only": "incomplete", "no_mesh": "failed",
                      "take_a": "ok", "take_b": "ok", "take_c": "ok"}
    reasons = {o.name: o.reason for o in res.outcomes}
    assert "missing.obj" in reasons["no_mesh"]
    assert "no object poses" in reasons["hand_only"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"] == 3 and set(summary["not_ok"]) == {"broken", "hand_only", "no_mesh"}
    for name in ("take_a", "take_b", "take_c"):
        assert (out / name / "result.npz").exists() and (out / name / "bag").is_dir()
    assert not (out / "no_mesh").exists()
    # the simulated grasp's contact forces are in the bag (take_c holds the object)
    from hand_control.report.series import contact_force_sum, load_bag

    data = load_bag(out / "take_c" / "bag")
    assert len(data.topics["sim/contacts"].msgs) == 6
    assert contact_force_sum(data.topics["sim/contacts"].msgs).max() > 0.5  # [N]


def test_dask_cluster_of_two_processes_gives_the_serial_results(archive, tmp_path):
    """Serial and Dask runs give bit-identical results (seeds derived from the names); a
    corrupt, an incomplete and a failing capture are named and skipped, the others finish."""
    from distributed import LocalCluster

    from hand_control.physcap.batch import BatchConfig, capture_seed, run_archive

    serial = run_archive(archive, tmp_path / "serial", TINY,
                         BatchConfig(workers=0, progress=False))
    _check_batch(serial, tmp_path / "serial")
    sched_file = tmp_path / "scheduler.json"  # as dask-jobqueue / dask-mpi clusters give it
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0",
                      scheduler_kwargs={"scheduler_file": str(sched_file)}) as cluster:
        assert len(cluster.workers) == 2
        dask = run_archive(archive, tmp_path / "dask", TINY,
                           BatchConfig(scheduler=str(sched_file), progress=False))
    _check_batch(dask, tmp_path / "dask")
    assert all(o.worker.startswith("tcp://") for o in dask.ok)
    by_name = {o.name: o for o in serial.outcomes}
    for o in dask.ok:
        s = by_name[o.name]
        assert o.seed == s.seed == capture_seed(TINY.seed, o.name)
        assert o.result.config.seed == o.seed
        assert results_equal(s.result, o.result) == [], o.name
        # the files on disk hold the same result
        assert results_equal(read_result(tmp_path / "dask" / o.name), s.result) == []
    assert len({o.seed for o in dask.ok}) == 3  # every capture its own seed


def test_capture_seed_depends_on_base_and_name_only():
    from hand_control.physcap.batch import capture_seed

    assert capture_seed(0, "take_a") == capture_seed(0, "take_a")
    assert capture_seed(0, "take_a") != capture_seed(0, "take_b")
    assert capture_seed(0, "take_a") != capture_seed(1, "take_a")
    # SHA-256 based: the same value in every process and Python version
    assert capture_seed(0, "take_a") == 0x7FFFFFFF & int.from_bytes(
        __import__("hashlib").sha256(b"0:take_a").digest()[:4], "little")


def test_cli_run_info_replay(archive, tmp_path, capsys):
    from hand_control.cli import main

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"n_samples": 8, "n_keep": 4, "seed": 11}))
    out = tmp_path / "out"
    rc = main(["physcap", "run", str(archive), "-o", str(out), "--workers", "0",
               "--config", str(cfg), "--no-progress"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert rc == 1  # not every capture could be optimised
    fig = json.loads(lines[-1])
    assert fig["ok"] == 3 and fig["captures"] == 6 and "no_mesh" in fig["not_ok"]
    assert any("take_a" in line and "ok" in line for line in lines)
    assert main(["physcap", "replay", str(out / "take_a")]) == 0
    text = capsys.readouterr().out
    assert "match" in text and "True" in text
    assert main(["physcap", "info", str(archive)]) == 1
    assert "broken" in capsys.readouterr().out
    assert main(["physcap", "info", str(out)]) == 0  # the run's summary
    assert "3 optimised" in capsys.readouterr().out
    # the output folder is never written over ...
    run = ["physcap", "run", str(archive), "-o", str(out), "--workers", "0", "--config",
           str(cfg), "--no-progress"]
    before = (out / "take_a" / "result.npz").stat().st_mtime_ns
    assert main(run) == 2
    assert "--resume" in capsys.readouterr().err
    # ... but --resume keeps its results and optimises only the others
    assert main([*run, "--resume"]) == 1
    fig = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert fig["kept"] == 3 and fig["ok"] == 0 and set(fig["not_ok"]) == {
        "broken", "hand_only", "no_mesh"}
    assert (out / "take_a" / "result.npz").stat().st_mtime_ns == before
    # results made with other settings are not mixed in
    assert main([*run, "--resume", "--seed", "12"]) == 2
    assert "other settings (seed=" in capsys.readouterr().err


def test_unreachable_scheduler_is_a_clear_error(archive, tmp_path, capsys):
    from hand_control.cli import main

    rc = main(["physcap", "run", str(archive), "-o", str(tmp_path / "o"), "--scheduler",
               "tcp://127.0.0.1:1", "--connect-timeout", "1", "--no-progress"])
    assert rc == 2
    assert "cannot start Dask on tcp://127.0.0.1:1" in capsys.readouterr().err


@pytest.mark.slow  # two local clusters (1 and 2 worker processes), one after the other
def test_measure_dask_speedup_runs_both_clusters_on_the_same_captures(archive):
    from hand_control.physcap.batch import measure_dask_speedup

    files = [archive / "take_a.npz", archive / "take_b.npz"]
    fig = measure_dask_speedup(files, TINY, quick=True)
    assert fig["dask_captures"] == 2 and fig["dask_failed"] == []
    assert fig["dask_identical"] is True
    assert fig["dask_1w_s"] > 0 and fig["dask_2w_s"] > 0
    assert fig["dask_speedup_2w"] == pytest.approx(fig["dask_1w_s"] / fig["dask_2w_s"])
    assert fig["dask_task_time_ratio"] == pytest.approx(
        fig["dask_2w_task_s"] / fig["dask_1w_task_s"])


_SLOW_OPTIMISER = '''
import time
from hand_control.physcap.capture import optimise_capture

def optimise(capture, config, progress=None):
    while capture.name == "endless":  # until the batch is interrupted
        time.sleep(0.05)
    return optimise_capture(capture, config, progress=progress)
'''


def test_interrupt_cancels_the_tasks_and_stops_the_cluster(archive, tmp_path):
    """SIGINT (Ctrl-C) during a Dask run: exit status 130, the finished capture written, the
    endless one cancelled in summary.json, and every worker process of the local cluster
    gone."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import psutil

    (tmp_path / "slowopt.py").write_text(_SLOW_OPTIMISER)
    arch = tmp_path / "arch"
    arch.mkdir()
    for name in ("endless", "take_a"):
        (arch / f"{name}.npz").write_bytes((archive / "take_a.npz").read_bytes())
    out = tmp_path / "out"
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(tmp_path)])}
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from hand_control.cli import main; "
         "sys.exit(main(sys.argv[1:]))", "physcap", "run", str(arch), "-o", str(out),
         "--workers", "2", "--samples", "8", "--optimiser", "slowopt:optimise",
         "--no-progress"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out / "take_a").exists():  # the fast capture finished (written whole)
            assert proc.poll() is None, proc.stdout.read()
            assert time.monotonic() < deadline, "take_a never finished"
            time.sleep(0.2)
        workers = psutil.Process(proc.pid).children(recursive=True)
        assert workers  # the local cluster's processes
        proc.send_signal(signal.SIGINT)
        text, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, text
    assert "interrupted" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["ok"] == 1
    assert summary["not_ok"]["endless"].startswith("cancelled")
    gone, alive = psutil.wait_procs(workers, timeout=60)
    assert not alive, [p.cmdline() for p in alive]


def test_a_scheduler_without_workers_is_a_clear_error(archive, tmp_path):
    from distributed import LocalCluster

    from hand_capture.errors import HandSuiteError
    from hand_control.physcap.batch import BatchConfig, run_archive

    with LocalCluster(n_workers=0, processes=True, dashboard_address=":0") as cluster:
        with pytest.raises(HandSuiteError, match="no Dask worker joined"):
            run_archive(archive, tmp_path / "o", TINY,
                        BatchConfig(scheduler=cluster.scheduler_address, progress=False,
                                    connect_timeout=1.0))


def test_a_capture_missing_where_the_task_runs_is_named(tmp_path):
    from hand_control.physcap.batch import CaptureJob, process_capture

    job = CaptureJob("gone", str(tmp_path / "gone.npz"), "npz", TINY)
    out = process_capture(job)
    assert out.status == "failed" and "same path on every worker" in out.reason


def test_cli_sample_writes_a_usable_archive(tmp_path, capsys):
    from hand_control.cli import main

    arch = tmp_path / "arch"
    assert main(["physcap", "sample", str(arch), "--scenarios", "lift_box,lift_ball"]) == 0
    assert (arch / "lift_box.npz").is_file() and (arch / "lift_ball").is_dir()
    entries = {e.name: e for e in list_archive(arch)}
    assert {n: (e.status, e.kind) for n, e in entries.items()} == {
        "lift_box": ("ok", "npz"), "lift_ball": ("ok", "bag")}
    assert main(["physcap", "sample", str(arch), "--scenarios", "lift_box"]) == 2
