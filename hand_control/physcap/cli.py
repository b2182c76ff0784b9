"""``hand-suite physcap run | info | sample | replay`` (registered by :mod:`hand_control.cli`).

    hand-suite physcap run ARCHIVE_DIR -o OUT [--workers N | --scheduler tcp://HOST:8786]
                           [--quick] [--object FILE] [--config FILE] [--samples N] [--seed S]
                           [--resume] [--hand left] [--no-progress]
    hand-suite physcap info ARCHIVE_DIR | OUT | RESULT_DIR | FILE.npz | BAG
    hand-suite physcap sample ARCHIVE_DIR [--scenarios lift_box,...] [--corruption tracker]
    hand-suite physcap replay RESULT_DIR [--tolerance-mm MM]
"""

from __future__ import annotations

import argparse
import signal
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from hand_capture.errors import InputError

#: ``--quick``: samples per step and samples kept (the default is the paper's 1500 and 150)
QUICK_SAMPLES, QUICK_KEEP = 200, 40


def add_parser(sub: Any) -> None:
    """Add the ``physcap`` command to the ``hand-suite`` sub-parsers."""
    ph = sub.add_parser("physcap", help="physics-based capture: optimise captures (batch on "
                        "Dask), inspect, replay")
    act = ph.add_subparsers(dest="physcap_action", required=True)
    r = act.add_parser("run", help="optimise every capture of an archive folder")
    r.add_argument("archive", help="folder of captures (*.npz, bag folders, *.mcap), or "
                   "one capture")
    r.add_argument("-o", "--output", required=True, help="results folder (one per capture)")
    r.add_argument("--workers", type=int, default=2,
                   help="local Dask worker processes (0 = serial in this process)")
    r.add_argument("--threads-per-worker", type=int, default=1)
    r.add_argument("--scheduler", default="", help="existing Dask scheduler, e.g. "
                   "tcp://HOST:8786, or its scheduler file (*.json); the archive must be at "
                   "the same path on its workers")
    r.add_argument("--connect-timeout", type=float, default=30.0,
                   help="seconds to wait for --scheduler")
    r.add_argument("--quick", action="store_true",
                   help=f"{QUICK_SAMPLES} samples per step instead of the paper's 1500")
    r.add_argument("--object", default=None, metavar="FILE",
                   help="object properties (YAML) for bags without a sidecar or metadata")
    r.add_argument("--config", default=None, metavar="FILE",
                   help="PhysCapConfig keys (flat YAML mapping)")
    r.add_argument("--samples", type=int, default=None, help="samples per step")
    r.add_argument("--seed", type=int, default=None, help="base seed (per capture: derived "
                   "from it and the capture's name)")
    r.add_argument("--min-frames", type=int, default=None, help="fewest frames a capture "
                   "may have")
    r.add_argument("--resume", action="store_true", help="keep the results already in "
                   "OUT (an interrupted run) and optimise the other captures")
    r.add_argument("--hand", default="right", choices=["right", "left"],
                   help="which hand of a bag is captured")
    r.add_argument("--optimiser", default="", metavar="MODULE:FUNCTION",
                   help="another optimiser with optimise_capture's signature, importable "
                   "on the workers (default: the suite's)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    i = act.add_parser("info", help="list an archive (status of every capture) or show a "
                       "result or capture file")
    i.add_argument("path")
    i.add_argument("--object", default=None, metavar="FILE")
    rp = act.add_parser("replay", help="re-simulate a saved result's control and compare")
    rp.add_argument("result", help="result folder (or its result.npz)")
    rp.add_argument("--tolerance-mm", type=float, default=1.0,
                    help="largest object / hand root deviation that counts as a match [mm]")
    sm = act.add_parser("sample", help="write a sample archive: simulated scenario "
                        "captures corrupted like a tracker (npz files and one bag)")
    sm.add_argument("output", help="archive folder to create")
    sm.add_argument("--scenarios", default="lift_box,lift_cylinder,lift_ball",
                    help="comma-separated config/scenarios names (the last one as a bag)")
    sm.add_argument("--corruption", default="tracker", choices=["tracker", "contacts", "drift"])
    sm.add_argument("--seed", type=int, default=0, help="corruption seed")
    ph.set_defaults(func=cmd_physcap)


def cmd_physcap(a: argparse.Namespace) -> int:
    return {"run": _run, "info": _info, "replay": _replay,
            "sample": _sample}[a.physcap_action](a)


def _sample(a: argparse.Namespace) -> int:
    from hand_control.physcap.capture import save_capture_npz
    from hand_control.physcap.output import write_capture_bag
    from hand_control.physcap.synth import corrupt, scenario_capture
    from hand_control.sim.scenario import load_scenario

    out = Path(a.output)
    names = [n for n in a.scenarios.split(",") if n]
    if not names:
        raise InputError("--scenarios names no scenario")
    taken = [n for n in names if (out / f"{n}.npz").exists() or (out / n).exists()]
    if taken:
        raise InputError(f"{out} already holds {taken}; choose another folder")
    out.mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(names):
        cap = corrupt(scenario_capture(load_scenario(name)), a.corruption, a.seed + i).capture
        path = (write_capture_bag(cap, out / name) if i == len(names) - 1 and len(names) > 1
                else save_capture_npz(cap, out / f"{name}.npz"))
        print(f"wrote {path} ({cap.n_frames} frames, {a.corruption} corruption)")
    return 0


def _config(a: argparse.Namespace) -> Any:
    from hand_capture.config import from_mapping, load_yaml
    from hand_control.physcap.capture import PhysCapConfig

    values: dict[str, Any] = {}
    if a.config:
        values = dict(load_yaml(a.config) or {})
    cfg = from_mapping(PhysCapConfig, values)
    if a.quick:
        cfg = replace(cfg, n_samples=min(cfg.n_samples, QUICK_SAMPLES),
                      n_keep=min(cfg.n_keep, QUICK_KEEP))
    if a.samples is not None:
        cfg = replace(cfg, n_samples=a.samples, n_keep=min(cfg.n_keep, a.samples))
    if a.seed is not None:
        cfg = replace(cfg, seed=a.seed)
    return cfg


def _default_object(path: str | None) -> Any:
    if not path:
        return None
    from hand_control.physcap.archive import load_object_yaml

    return load_object_yaml(path)


def _on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _run(a: argparse.Namespace) -> int:
    from hand_capture.bench import json_line, print_table
    from hand_control.physcap.archive import ArchiveConfig
    from hand_control.physcap.batch import TABLE_HEADERS, BatchConfig, run_archive

    cfg = _config(a)
    batch = BatchConfig(workers=a.workers, threads_per_worker=a.threads_per_worker,
                        scheduler=a.scheduler, progress=not a.no_progress,
                        connect_timeout=a.connect_timeout, resume=a.resume)
    arch = ArchiveConfig(hand=a.hand, **({} if a.min_frames is None
                                         else {"min_frames": a.min_frames}))
    old = signal.signal(signal.SIGTERM, _on_sigterm)  # a kill closes the cluster like Ctrl-C
    try:
        res = run_archive(a.archive, a.output, cfg, batch,
                          default_object=_default_object(a.object), archive=arch,
                          optimiser=a.optimiser)
    except KeyboardInterrupt:
        print(f"hand-suite physcap run: interrupted; the results finished so far are in "
              f"{a.output} (summary.json); the same command with --resume continues")
        return 130
    finally:
        signal.signal(signal.SIGTERM, old)
    print_table(f"physcap run: {len(res.ok)} of {len(res.outcomes)} captures optimised "
                f"({res.mode}, {cfg.n_samples} samples per step, {res.wall_s:.1f} s)",
                TABLE_HEADERS, res.table_rows())
    print(json_line({"physcap": "run", **res.figures()}))
    return 0 if not res.failed else 1


def _info(a: argparse.Namespace) -> int:
    from hand_capture.bench import print_table
    from hand_control.physcap.archive import list_archive

    p = Path(a.path)
    if (p / "summary.json").is_file():  # the output folder of a run
        import json

        s = json.loads((p / "summary.json").read_text())
        rows = [[c["name"], c["status"], c["frames"], c["seconds"],
                 c.get("summary", {}).get("success", ""),
                 c.get("summary", {}).get("final_error_mm", ""), c["output"] or c["reason"]]
                for c in s.get("captures_detail", [])]
        print_table(f"physcap run {p}: {s['ok']} optimised, {s.get('kept', 0)} kept of "
                    f"{s['captures']} ({s['mode']}{', interrupted' if s['interrupted'] else ''})",
                    ["capture", "status", "frames", "seconds", "success",
                     "final object err [mm]", "output / reason"], rows)
        return 0
    if p.is_dir() and not (p / "result.npz").exists() and not (p / "metadata.yaml").exists():
        entries = list_archive(p, _default_object(a.object))
        print_table(f"archive {p}: {sum(e.ok for e in entries)} of {len(entries)} captures "
                    f"usable", ["capture", "kind", "status", "frames", "duration [s]",
                                "object", "object from", "reason"],
                    [[e.name, e.kind, e.status, e.frames, e.duration_s, e.object_kind,
                      e.object_source, e.reason] for e in entries])
        return 0 if all(e.ok for e in entries) else 1
    if (p / "result.npz").exists() or (
            p.suffix == ".npz" and _npz_format(p).startswith("hand_suite.physcap.result")):
        from hand_control.physcap.output import read_result

        r = read_result(p)
        s = r.summary()
        cfg = s.pop("config")
        for k, v in s.items():
            print(f"{k:16s} {v:.4g}" if isinstance(v, float) else f"{k:16s} {v}")
        print(f"{'object':16s} {asdict(r.obj)}")
        print(f"{'config':16s} " + ", ".join(f"{k}={v}" for k, v in cfg.items()))
        return 0
    from hand_control.physcap.archive import read_capture_bag
    from hand_control.physcap.capture import load_capture_npz

    if p.suffix == ".npz":
        c, source = load_capture_npz(p), "npz"
    else:  # a bag: what the archive would read from it
        c, source = read_capture_bag(p, _default_object(a.object))
    print(f"capture {c.name}: {c.n_frames} frames, {c.duration:.3f} s, object "
          f"{asdict(c.obj)} (from {source}), keypoints "
          f"{'yes' if c.keypoints is not None else 'no'}")
    return 0


def _npz_format(path: Path) -> str:
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            return str(z["format"]) if "format" in z.files else ""
    except (OSError, ValueError, EOFError) as e:
        raise InputError(f"{path}: not a readable npz ({e})") from e


def _replay(a: argparse.Namespace) -> int:
    from hand_control.physcap.output import read_result, replay_match

    r = read_result(a.result)
    m = replay_match(r, tolerance_m=a.tolerance_mm * 1e-3)
    for k, v in m.items():
        print(f"{k:28s} {v:.4g}" if isinstance(v, float) else f"{k:28s} {v}")
    return 0 if m["match"] else 1
