"""Build the HTML report of a recorded bag: every figure and number comes from the bag.

Sections appear when their topics were recorded:

* tracking error against ground truth (``hand/pose`` vs ``hand/pose_truth``, same stamps):
  mean keypoint position error [mm] from the hand model's forward kinematics;
* per-stage latency (receive time minus the source image stamp every stage keeps) for the
  camera, pose, command and servo-write topics;
* contact forces over time (simulated ``sim/contacts``, planned ``control/contact_forces``);
* object trajectory against its target (``sim/object_pose`` vs ``control/object_target``);
* servo positions against their goals (``servo/joint_states`` vs ``servo/goal``);
* the grasp phase over time (``control/grasp_phase``);
* rendered frames of the simulated grasp, when a frame renderer is given.
"""

from __future__ import annotations

import html
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_control.report.series import (
    SAME_CLOCK_MS,
    BagData,
    contact_force_sum,
    joint_series,
    latency_ms,
    load_bag,
    match_by_stamp,
    max_lift_mm,
    positions,
    stamps_ns,
)

#: Topics whose header stamp is the source image stamp, in pipeline order.
LATENCY_STAGES = (
    ("camera", "camera/depth/image_raw"),
    ("pose", "hand/pose"),
    ("command", "control/joint_command"),
    ("servo write", "servo/goal"),
)
_SKIP_ALWAYS = ("camera/color/image_raw", "hand/debug_image", "hand/markers", "rosout",
                "parameter_events")


@dataclass
class ReportResult:
    """Where the report went and the numbers it shows."""

    html: Path
    figures: list[Path] = field(default_factory=list)
    numbers: dict[str, float] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)


def _plt():
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _pose_vectors(msgs: list[object]) -> np.ndarray:
    """(T, 27) model poses from HandPose messages."""
    from hand_capture.posemsg import pose_from_msg

    return np.array([pose_from_msg(m) for m in msgs])


def _tracking(data: BagData, res: ReportResult, plt, out: Path) -> str:
    if not data.has("hand/pose", "hand/pose_truth"):
        res.missing.append("tracking error (needs hand/pose and hand/pose_truth)")
        return ""
    from hand_capture.model import HandModel

    est, tru = data.topics["hand/pose"], data.topics["hand/pose_truth"]
    ia, ib = match_by_stamp(stamps_ns(est.msgs), stamps_ns(tru.msgs))
    if ia.size == 0:
        res.missing.append("tracking error (no hand/pose stamp matches hand/pose_truth)")
        return ""
    model = HandModel()
    pe = _pose_vectors([est.msgs[i] for i in ia])
    pt = _pose_vectors([tru.msgs[i] for i in ib])
    ke = model.forward(pe).joint_positions
    kt = model.forward(pt).joint_positions
    err = np.linalg.norm(ke - kt, axis=-1) * 1000.0  # (T, 21) [mm]
    mean_err, max_err = err.mean(axis=1), err.max(axis=1)
    t = data.rel_s([est.t_ns[i] for i in ia])
    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.plot(t, mean_err, label="mean keypoint error")
    ax.plot(t, max_err, alpha=0.6, label="largest keypoint error")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("error [mm]")
    ax.set_title("tracking error against ground truth")
    ax.legend()
    res.numbers.update(tracking_mean_err_mm=float(mean_err.mean()),
                       tracking_median_err_mm=float(np.median(mean_err)),
                       tracking_success_20mm=float((max_err < 20.0).mean()),
                       tracked_frames=float(ia.size), truth_frames=float(len(tru.msgs)))
    return _save(fig, out / "tracking_error.png", res, plt)


def _latency(data: BagData, res: ReportResult, plt, out: Path) -> str:
    stages, lat = [], []
    for label, topic in LATENCY_STAGES:
        if not data.has(topic):
            continue
        _, v = latency_ms(data.topics[topic])
        same = np.abs(v) <= SAME_CLOCK_MS
        if not same.any():
            # stamps from another clock (e.g. simulation time) than the recording's
            res.missing.append(f"latency of {topic} (its stamps are not on the recorder's "
                               f"clock: median offset {np.median(v) / 1e3:.3g} s)")
            continue
        if not same.all():  # e.g. commands sent before the first hand pose (sim stamps)
            res.numbers[f"latency_{label.replace(' ', '_')}_other_clock_msgs"] = float(
                (~same).sum())
            v = v[same]
        stages.append((label, topic))
        lat.append(v)
    if not stages:
        res.missing.append("latency (no stamped pipeline topic on the recording clock)")
        return ""
    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.boxplot(lat, showfliers=True)
    ax.set_xticks(range(1, len(stages) + 1),
                  [f"{label}\n{topic}" for label, topic in stages])
    ax.set_ylabel("since source image stamp [ms]")
    ax.set_title("per-stage latency")
    for (label, _), v in zip(stages, lat, strict=True):
        key = label.replace(" ", "_")
        res.numbers[f"latency_{key}_p50_ms"] = float(np.percentile(v, 50))
        res.numbers[f"latency_{key}_p99_ms"] = float(np.percentile(v, 99))
    return _save(fig, out / "latency.png", res, plt)


def _contacts(data: BagData, res: ReportResult, plt, out: Path) -> str:
    pairs = [(n, lbl) for n, lbl in (("sim/contacts", "simulated"),
                                     ("control/contact_forces", "planned (QP)")) if data.has(n)]
    if not pairs:
        res.missing.append("contact forces (needs sim/contacts or control/contact_forces)")
        return ""
    fig, ax = plt.subplots(figsize=(9, 3.2))
    for name, label in pairs:
        td = data.topics[name]
        ax.plot(data.rel_s(td.t_ns), contact_force_sum(td.msgs), label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("total contact force [N]")
    ax.set_title("contact forces")
    ax.legend()
    return _save(fig, out / "contact_forces.png", res, plt)


def _object(data: BagData, res: ReportResult, plt, out: Path) -> str:
    if not data.has("sim/object_pose"):
        res.missing.append("object trajectory (needs sim/object_pose)")
        return ""
    obj = data.topics["sim/object_pose"]
    po, to = positions(obj.msgs), data.rel_s(obj.t_ns)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.0), sharex=True)
    tgt = data.topics.get("control/object_target")
    has_tgt = tgt is not None and bool(tgt.msgs)
    pt = positions(tgt.msgs) if has_tgt else None
    for k, ax in enumerate(axes):
        ax.plot(to, po[:, k], label="object")
        if has_tgt:
            ax.plot(data.rel_s(tgt.t_ns), pt[:, k], "--", label="target")
        ax.set_title("xyz"[k] + " [m]")
        ax.set_xlabel("time [s]")
    axes[0].legend()
    res.numbers["object_max_lift_mm"] = max_lift_mm(po)
    if has_tgt:
        idx = np.clip(np.searchsorted(np.asarray(tgt.t_ns), np.asarray(obj.t_ns)) - 1, 0, None)
        valid = np.asarray(obj.t_ns) >= tgt.t_ns[0]
        if valid.any():
            e = np.linalg.norm(po[valid] - pt[idx[valid]], axis=1) * 1000.0
            res.numbers["object_err_mean_mm"] = float(e.mean())
    return _save(fig, out / "object_trajectory.png", res, plt)


def _servo(data: BagData, res: ReportResult, plt, out: Path) -> str:
    if not data.has("servo/joint_states"):
        res.missing.append("servo positions (needs servo/joint_states)")
        return ""
    js = data.topics["servo/joint_states"]
    names = list(js.msgs[0].name)[:4]
    fig, ax = plt.subplots(figsize=(9, 3.2))
    pos = joint_series(js.msgs, "name", "position", names)
    goal = data.topics.get("servo/goal")
    g = (joint_series(goal.msgs, "joint_names", "positions", names)
         if goal is not None and goal.msgs else None)
    for k, n in enumerate(names):
        line, = ax.plot(data.rel_s(js.t_ns), pos[:, k], label=f"{n} measured")
        if g is not None:
            ax.plot(data.rel_s(goal.t_ns), g[:, k], "--", color=line.get_color(),
                    label=f"{n} goal")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("servo angle [rad]")
    ax.set_title("servo positions against goals")
    ax.legend(fontsize=7, ncol=2)
    return _save(fig, out / "servo.png", res, plt)


def _phases(data: BagData, res: ReportResult, plt, out: Path) -> str:
    if not data.has("control/grasp_phase"):
        return ""
    td = data.topics["control/grasp_phase"]
    fig, ax = plt.subplots(figsize=(9, 2.0))
    ax.step(data.rel_s(td.t_ns), [m.phase for m in td.msgs], where="post")
    ax.set_yticks(range(4), ["reaching", "closing", "manipulation", "releasing"])
    ax.set_xlabel("time [s]")
    ax.set_title("grasp phase")
    return _save(fig, out / "grasp_phase.png", res, plt)


def _save(fig, path: Path, res: ReportResult, plt) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    res.figures.append(path)
    return f'<figure><img src="{path.name}" alt="{path.stem}"></figure>'


def build_report(
    bag: str | Path,
    out_dir: str | Path,
    frames_fn: Callable[[BagData, Path], list[Path]] | None = None,
    title: str = "hand_suite run report",
) -> ReportResult:
    """Write ``out_dir/index.html`` (and its PNG figures) from ``bag``.

    Args:
        bag: the recorded bag.
        out_dir: folder for the report (created).
        frames_fn: optional renderer of simulation frames: (bag data, out_dir) -> PNG paths.
        title: page title.
    """
    plt = _plt()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = load_bag(bag, skip=_SKIP_ALWAYS)
    res = ReportResult(html=out / "index.html")
    sections = [f(data, res, plt, out)
                for f in (_tracking, _latency, _contacts, _object, _servo, _phases)]
    frames_html = ""
    if frames_fn is not None:
        frames = frames_fn(data, out)
        res.figures += frames
        frames_html = "".join(f'<figure class="frame"><img src="{p.name}" alt="{p.stem}">'
                              f'<figcaption>{html.escape(p.stem)}</figcaption></figure>'
                              for p in frames)
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.4g}</td></tr>"
                   for k, v in sorted(res.numbers.items()))
    counts = "".join(f"<tr><td>/{html.escape(t)}</td><td>{len(td.msgs)}</td></tr>"
                     for t, td in sorted(data.topics.items()))
    missing = "".join(f"<li>{html.escape(m)}</li>" for m in res.missing)
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}
img{{max-width:100%}} figure.frame{{display:inline-block;width:32%;margin:2px}}
td{{padding:2px 10px}} table{{border-collapse:collapse}}
tr:nth-child(even){{background:#f2f2f2}}</style></head>
<body><h1>{html.escape(title)}</h1>
<p>Bag: <code>{html.escape(str(Path(bag).resolve()))}</code>. Every figure and number below is
computed from the messages in this bag.</p>
<h2>Numbers</h2><table>{rows}</table>
{''.join(sections)}
{'<h2>Simulated grasp</h2>' + frames_html if frames_html else ''}
<h2>Topics in the bag</h2><table>{counts}</table>
{'<h2>Not in this bag</h2><ul>' + missing + '</ul>' if missing else ''}
</body></html>
"""
    res.html.write_text(page)
    return res
