"""Batch physics capture of an archive, serially or on a Dask distributed cluster.

``hand-suite physcap run ARCHIVE_DIR -o OUT [--scheduler tcp://HOST:8786] [--workers N]``:

* :func:`~hand_control.physcap.archive.list_archive` validates every capture first; a corrupt
  or incomplete one is reported with its name and reason and not submitted.
* Each valid capture is one task. A worker gets a :class:`CaptureJob` (the capture's path,
  the object properties and the configs: small frozen dataclasses), loads the capture from
  its file and builds its own MuJoCo model from it; no model or array crosses the network.
  With ``--scheduler`` the archive must be readable at the same path on the workers (a
  shared file system); the client writes the outputs.
* The seed of a capture is derived from the base seed and the capture's name
  (:func:`capture_seed`, SHA-256: the same in every process, unlike ``hash()``), so a Dask
  run gives bit-identical results to a serial run, in any order and on any worker.
* A capture whose optimisation fails is reported with its name and reason; the others
  finish (the task returns a failed :class:`CaptureOutcome` instead of raising; a worker
  that dies is reported the same way).
* Progress: one tqdm bar over captures and one over frames; workers report frames as
  worker events (``physcap-frames``, throttled) that the client subscribes to.
* Ctrl-C (or SIGTERM in the CLI) cancels the pending tasks and closes the client and the
  local cluster; the results written so far stay (each result folder appears only when
  complete) and ``--resume`` continues with the others.
* Before the first task the client waits for a worker and has every worker import the
  optimiser, so a cluster without workers or without hand_suite is a clear error.

By default a :class:`distributed.LocalCluster` with worker *processes* (one thread each) is
started; ``--workers 0`` runs serially in this process (the same code path per capture).
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, HandSuiteError, InputError
from hand_control.physcap.archive import (
    ArchiveCaptureError,
    ArchiveConfig,
    ArchiveEntry,
    ObjectProperties,
    list_archive,
    load_entry,
)
from hand_control.physcap.capture import Capture, PhysCapConfig, PhysCapResult

__all__ = ["BatchConfig", "BatchResult", "CaptureJob", "CaptureOutcome", "capture_seed",
           "dask_client", "measure_dask_speedup", "process_capture", "run_archive",
           "run_batch"]

#: worker event topic of frame progress
FRAME_TOPIC = "physcap-frames"
#: seconds between two frame events of one task
_EVENT_PERIOD = 0.25


@dataclass(frozen=True)
class BatchConfig:
    """Where and how a batch runs."""

    workers: int = param(2, "local worker processes; 0 = serial in this process", lo=0,
                         hi=256)
    threads_per_worker: int = param(1, "threads of each local worker (tasks at once)",
                                    lo=1, hi=64)
    scheduler: str = param("", "address of an existing Dask scheduler (tcp://HOST:8786), or "
                           "its scheduler file (*.json, as 'dask scheduler --scheduler-file' "
                           "and dask-jobqueue / dask-mpi write it); "
                           "empty = start a local cluster")
    progress: bool = param(True, "tqdm bars over captures and frames (stderr)")
    write: bool = param(True, "write each result (npz + bag) under the output folder")
    resume: bool = param(False, "keep the results an earlier run (e.g. interrupted) left in "
                         "the output folder and optimise only the other captures")
    connect_timeout: float = param(30.0, "seconds to wait for --scheduler", lo=1.0,
                                   hi=3600.0)

    def __post_init__(self) -> None:
        validate(self)
        if self.scheduler and not self.scheduler.endswith(".json") and \
                not self.scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://",
                                               "ws://", "wss://")):
            raise ConfigError(f"BatchConfig.scheduler {self.scheduler!r} is neither a "
                              f"scheduler address like tcp://HOST:8786 nor a scheduler file "
                              f"(*.json)")


def capture_seed(base_seed: int, name: str) -> int:
    """The seed of capture ``name`` in a run with ``base_seed``: the first 31 bits of
    SHA-256(``"<base_seed>:<name>"``) (the same in every process and on every machine)."""
    digest = hashlib.sha256(f"{int(base_seed)}:{name}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFF_FFFF


@dataclass(frozen=True)
class CaptureJob:
    """What a worker needs for one capture: paths and configs, never models or arrays."""

    name: str
    path: str
    kind: str
    config: PhysCapConfig
    default_object: ObjectProperties | None = None
    archive: ArchiveConfig = field(default_factory=ArchiveConfig)
    #: ``module:function`` of the optimiser (same signature as optimise_capture), imported
    #: where the task runs; empty = :func:`~hand_control.physcap.capture.optimise_capture`
    optimiser: str = ""

    @classmethod
    def from_entry(cls, entry: ArchiveEntry, config: PhysCapConfig,
                   default_object: ObjectProperties | None = None,
                   archive: ArchiveConfig | None = None, optimiser: str = "") -> CaptureJob:
        return cls(entry.name, str(Path(entry.path).resolve()), entry.kind, config,
                   default_object,
                   archive or ArchiveConfig(), optimiser)

    @property
    def seeded_config(self) -> PhysCapConfig:
        """``config`` with the capture's own seed (:func:`capture_seed`)."""
        return replace(self.config, seed=capture_seed(self.config.seed, self.name))


@dataclass
class CaptureOutcome:
    """How one capture ended.

    Attributes:
        name: the capture.
        status: ``ok``, ``failed`` (optimisation raised), ``corrupt`` / ``incomplete``
            (archive validation), ``cancelled`` (Ctrl-C).
        reason: why it is not ok.
        frames: frames of the result (ok) or of the capture.
        seconds: wall time of the task [s] (load + optimise).
        seed: the capture's seed.
        worker: where it ran (``local`` for a serial run).
        result: the optimised capture (ok only).
        output: the result folder when written.
    """

    name: str
    status: str
    reason: str = ""
    frames: int = 0
    seconds: float = 0.0
    seed: int = 0
    worker: str = "local"
    result: PhysCapResult | None = None
    output: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


ProgressFn = Callable[[int, int], None]


def process_capture(job: CaptureJob, progress: ProgressFn | None = None,
                    optimise: Callable[..., PhysCapResult] | None = None) -> CaptureOutcome:
    """Load and optimise one capture; every failure becomes a failed outcome (the batch
    goes on). This is what a serial run calls and what a Dask task runs.

    Args:
        job: the capture and configs.
        progress: ``progress(done_steps, total_steps)`` during the optimisation.
        optimise: the optimiser (default :func:`~hand_control.physcap.capture.optimise_capture`).
    """
    cfg = job.seeded_config
    t0 = time.perf_counter()
    frames = 0
    if not Path(job.path).exists():  # e.g. a worker of a cluster without the shared folder
        import socket

        return CaptureOutcome(job.name, "failed", f"{job.path} not found on "
                              f"{socket.gethostname()}: the archive must be at the same path "
                              f"on every worker (a shared file system)", 0, 0.0, cfg.seed)
    try:
        optimise = optimise or _optimiser(job.optimiser)
        entry = ArchiveEntry(job.name, Path(job.path), job.kind, "ok")
        cap: Capture = load_entry(entry, job.default_object, job.archive)
        frames = cap.n_frames
        res = optimise(cap, cfg, progress=progress)
    except ArchiveCaptureError as e:
        return CaptureOutcome(job.name, e.status, e.reason, frames,
                              time.perf_counter() - t0, cfg.seed)
    except HandSuiteError as e:
        return CaptureOutcome(job.name, "failed", f"{type(e).__name__}: {e}", frames,
                              time.perf_counter() - t0, cfg.seed)
    except Exception as e:  # a bug in one capture must not end the batch: report it
        where = traceback.extract_tb(e.__traceback__)[-1]
        return CaptureOutcome(job.name, "failed", f"{type(e).__name__}: {e} (at "
                              f"{Path(where.filename).name}:{where.lineno})", frames,
                              time.perf_counter() - t0, cfg.seed)
    return CaptureOutcome(job.name, "ok", "", int(res.times.shape[0]),
                          time.perf_counter() - t0, cfg.seed, result=res)


def _optimiser(spec: str) -> Callable[..., PhysCapResult]:
    if not spec:
        from hand_control.physcap.capture import optimise_capture

        return optimise_capture
    import importlib

    module, _, func = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as e:
        raise InputError(f"optimiser {spec!r} cannot be imported: {e}") from e


def _dask_task(job: CaptureJob) -> CaptureOutcome:
    """A Dask task: :func:`process_capture` with frame progress sent as worker events."""
    from distributed import get_worker

    worker = get_worker()
    last = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.monotonic()
        if done >= total or now - last[0] >= _EVENT_PERIOD:
            last[0] = now
            worker.log_event(FRAME_TOPIC, {"name": job.name, "done": int(done),
                                           "total": int(total)})

    out = process_capture(job, progress)
    out.worker = str(worker.address)
    return out


def _warm_worker() -> str:
    """Import the optimiser's modules on a worker (before a timed run)."""
    import importlib

    for mod in ("mujoco", "hand_control.physcap.archive", "hand_control.physcap.optimise"):
        importlib.import_module(mod)
    return "ok"


@contextmanager
def dask_client(workers: int = 2, scheduler: str = "", threads_per_worker: int = 1,
                connect_timeout: float = 30.0) -> Iterator[Any]:
    """A Dask client: connected to ``scheduler``, or to a new LocalCluster of ``workers``
    processes with ``threads_per_worker`` threads each (closed on exit, also on Ctrl-C).

    Raises:
        HandSuiteError: the scheduler cannot be reached or the cluster does not start.
    """
    from distributed import Client, LocalCluster

    cluster = None
    try:
        if scheduler.endswith(".json"):
            if not Path(scheduler).is_file():
                raise HandSuiteError(f"scheduler file {scheduler} not found")
            client = Client(scheduler_file=scheduler, timeout=connect_timeout)
        elif scheduler:
            client = Client(scheduler, timeout=connect_timeout)
        else:
            # ":0": the scheduler's HTTP routes (and a dashboard, with bokeh) on a free port,
            # so clusters of other runs on this machine never collide on 8787
            cluster = LocalCluster(n_workers=max(1, workers),
                                   threads_per_worker=threads_per_worker, processes=True,
                                   dashboard_address=":0", silence_logs=logging.ERROR)
            client = Client(cluster)
    except (OSError, TimeoutError) as e:
        if cluster is not None:
            cluster.close()
        where = scheduler or f"a local cluster of {workers} workers"
        raise HandSuiteError(f"cannot start Dask on {where}: {type(e).__name__}: {e}") from e
    try:
        yield client
    finally:
        try:
            client.close()
        finally:
            if cluster is not None:
                cluster.close()


@dataclass
class BatchResult:
    """Every capture's outcome and the batch's timing."""

    outcomes: list[CaptureOutcome]
    wall_s: float
    mode: str  # "serial", "local N workers" or the scheduler address
    interrupted: bool = False

    @property
    def ok(self) -> list[CaptureOutcome]:
        return [o for o in self.outcomes if o.ok]

    @property
    def failed(self) -> list[CaptureOutcome]:
        """Captures without a result (kept ones, status ``kept``, have one)."""
        return [o for o in self.outcomes if o.status not in ("ok", "kept")]

    def figures(self) -> dict[str, Any]:
        """JSON-ready summary (the CLI's last line)."""
        ok = self.ok
        frames = sum(o.frames for o in ok)
        task_s = sum(o.seconds for o in ok)
        res = [o.result for o in ok if o.result is not None]
        return {
            "captures": len(self.outcomes), "ok": len(ok),
            "kept": sum(o.status == "kept" for o in self.outcomes),
            "not_ok": {o.name: f"{o.status}: {o.reason}" for o in self.failed},
            "frames": frames, "wall_s": self.wall_s,
            "s_per_frame": task_s / frames if frames else None,
            "wall_s_per_frame": self.wall_s / frames if frames else None,
            "success_rate": (sum(bool(r.success) for r in res) / len(res)) if res else None,
            "mode": self.mode, "interrupted": self.interrupted,
        }

    def table_rows(self) -> list[list[Any]]:
        rows = []
        for o in self.outcomes:
            r = o.result
            rows.append([o.name, o.status, o.frames, o.seconds,
                         o.seconds / o.frames if o.ok and o.frames else "",
                         "" if r is None else ("yes" if r.success else "no"),
                         "" if r is None else r.final_error_m * 1e3,
                         o.output or o.reason])
        return rows


TABLE_HEADERS = ["capture", "status", "frames", "seconds", "s/frame", "success",
                 "final object err [mm]", "output / reason"]


class _Bars:
    """tqdm bars over captures and frames (disabled: no output)."""

    def __init__(self, enabled: bool, n_captures: int, n_frames: int) -> None:
        from tqdm import tqdm

        self.captures = tqdm(total=n_captures, desc="captures", unit="capture",
                             position=0, disable=not enabled, file=sys.stderr)
        self.frames = tqdm(total=n_frames, desc="frames", unit="frame", position=1,
                           disable=not enabled, file=sys.stderr)
        self._done: dict[str, int] = {}
        self._lock = threading.Lock()

    def frame_progress(self, name: str, done: int, total: int, frames: int) -> None:
        """A capture's optimisation reached step ``done`` of ``total`` (any thread); its
        frames on the bar are scaled to the capture's ``frames``."""
        with self._lock:
            self._done[name] = round(frames * min(done, total) / max(total, 1))

    def capture_done(self, name: str, frames: int) -> None:
        with self._lock:
            self._done[name] = frames
        self.captures.update(1)
        self.refresh()

    def refresh(self) -> None:
        with self._lock:
            n = sum(self._done.values())
        if n > self.frames.n:
            self.frames.update(n - self.frames.n)

    def close(self) -> None:
        self.frames.close()
        self.captures.close()


def _finish(outcome: CaptureOutcome, out_dir: Path | None, write: bool) -> None:
    """Write an ok outcome's result into ``out_dir/NAME``: built in a hidden folder and
    renamed when complete, so the folder never holds half a result (Ctrl-C while writing:
    the outcome becomes cancelled). Updates ``outcome`` in place."""
    if not (write and out_dir is not None and outcome.ok and outcome.result is not None):
        return
    import shutil

    from hand_control.physcap.output import write_result

    final = out_dir / outcome.name
    tmp = out_dir / f".{outcome.name}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        write_result(outcome.result, tmp)
        tmp.rename(final)
        outcome.output = str(final)
    except HandSuiteError as e:
        outcome.status, outcome.reason = "failed", f"writing the result: {e}"
    except BaseException:
        outcome.status, outcome.reason = "cancelled", "interrupted while writing its result"
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _kept(folder: Path, name: str, config: PhysCapConfig) -> CaptureOutcome:
    """The outcome of a result an earlier run left (``--resume``): refused when it was made
    with other settings (all but ``n_threads``) or this capture's seed."""
    from dataclasses import asdict

    from hand_control.physcap.output import read_result

    try:
        old = read_result(folder)
    except InputError as e:
        raise InputError(f"--resume: {folder} is not a finished result ({e}); move it away"
                         ) from e
    want = asdict(replace(config, seed=capture_seed(config.seed, name), n_threads=1))
    have = asdict(replace(old.config, n_threads=1))
    if want != have:
        diff = sorted(k for k in want if want[k] != have.get(k))
        raise InputError(f"--resume: the result in {folder} was made with other settings "
                         f"({', '.join(f'{k}={have.get(k)}' for k in diff)}); use another "
                         f"output folder")
    return CaptureOutcome(name, "kept", "result of an earlier run (--resume)",
                          int(old.times.shape[0]), 0.0, want["seed"], output=str(folder))


def run_batch(entries: Sequence[ArchiveEntry], config: PhysCapConfig,
              out_dir: str | Path | None = None, batch: BatchConfig | None = None, *,
              default_object: ObjectProperties | None = None,
              archive: ArchiveConfig | None = None, optimiser: str = "") -> BatchResult:
    """Optimise every ok entry (serially or on Dask, :class:`BatchConfig`); entries that are
    not ok are reported with their reason. Outcomes are in the entries' order.

    Raises:
        HandSuiteError: the cluster cannot be started or reached; KeyboardInterrupt after
            cancelling the tasks and closing the cluster (what finished is written).
    """
    batch = batch or BatchConfig()
    out = Path(out_dir) if out_dir is not None else None
    if out is not None and batch.write:
        out.mkdir(parents=True, exist_ok=True)
    taken = ([e.name for e in entries if e.ok and (out / e.name).exists()]
             if out is not None and batch.write else [])
    if taken and not batch.resume:
        raise InputError(f"{out} already holds results for {taken}; choose another output "
                         f"folder, move them away, or keep them with --resume")
    outcomes: dict[str, CaptureOutcome] = {
        e.name: CaptureOutcome(e.name, e.status, e.reason,
                               seed=capture_seed(config.seed, e.name))
        for e in entries if not e.ok}
    for name in taken:
        outcomes[name] = _kept(out / name, name, config)
    jobs = {e.name: CaptureJob.from_entry(e, config, default_object, archive, optimiser)
            for e in entries if e.ok and e.name not in outcomes}
    frames = {e.name: e.frames for e in entries if e.name in jobs}
    bars = _Bars(batch.progress, len(jobs), sum(frames.values()))
    t0 = time.perf_counter()
    interrupted = False
    mode = ("serial" if batch.workers == 0 and not batch.scheduler else
            batch.scheduler or f"local cluster, {batch.workers} worker processes")
    try:
        if mode == "serial":
            for name, job in jobs.items():

                def progress(done: int, total: int, name: str = name) -> None:
                    bars.frame_progress(name, done, total, frames[name])
                    bars.refresh()

                o = outcomes[name] = process_capture(job, progress)
                _finish(o, out, batch.write)
                bars.capture_done(name, frames[name])
        else:
            _run_dask(jobs, frames, outcomes, bars, out, batch)
    except KeyboardInterrupt:
        interrupted = True
        for name in jobs:
            outcomes.setdefault(name, CaptureOutcome(name, "cancelled", "interrupted (Ctrl-C)"))
        raise
    finally:
        bars.close()
        wall = time.perf_counter() - t0
        order = [e.name for e in entries]
        result = BatchResult([outcomes[n] for n in order if n in outcomes], wall, mode,
                             interrupted)
        if out is not None and batch.write:
            (out / "summary.json").write_text(json.dumps(
                {**result.figures(), "captures_detail": [
                    {"name": o.name, "status": o.status, "reason": o.reason,
                     "frames": o.frames, "seconds": o.seconds, "seed": o.seed,
                     "worker": o.worker, "output": o.output,
                     **({} if o.result is None else {"summary": _summary(o.result)})}
                    for o in result.outcomes]}, indent=1, default=str))
    return result


def _summary(r: PhysCapResult) -> dict[str, Any]:
    s = r.summary()
    s.pop("config", None)
    return s


def _run_dask(jobs: dict[str, CaptureJob], frames: dict[str, int],
              outcomes: dict[str, CaptureOutcome], bars: _Bars, out: Path | None,
              batch: BatchConfig) -> None:
    from distributed import as_completed

    if not jobs:
        return
    with dask_client(batch.workers, batch.scheduler, batch.threads_per_worker,
                     batch.connect_timeout) as client:
        _ready(client, batch)

        def on_event(event: Any) -> None:
            _, msg = event
            if isinstance(msg, dict) and msg.get("name") in frames:
                bars.frame_progress(msg["name"], msg["done"], msg["total"],
                                    frames[msg["name"]])

        client.subscribe_topic(FRAME_TOPIC, on_event)
        futures = {client.submit(_dask_task, job, key=f"physcap-{name}-{id(jobs)}",
                                 pure=False, retries=0): name for name, job in jobs.items()}
        ac = as_completed(list(futures))
        try:
            while not ac.is_empty():
                batch_done = ac.next_batch(block=False) if ac.has_ready() else []
                for fut in batch_done:
                    name = futures[fut]
                    try:  # (a task its dead worker lost is recomputed: result() waits)
                        o = fut.result()
                    except Exception as exc:  # raised outside process_capture, or every
                        # worker that tried it died (KilledWorker)
                        o = CaptureOutcome(name, "failed", f"{type(exc).__name__}: {exc}",
                                           seed=jobs[name].seeded_config.seed)
                    outcomes[name] = o
                    _finish(o, out, batch.write)
                    bars.capture_done(name, frames[name])
                if not batch_done:
                    bars.refresh()
                    time.sleep(0.1)
        except BaseException:
            client.cancel(list(futures))
            raise
        finally:
            try:
                client.unsubscribe_topic(FRAME_TOPIC)
            except Exception:  # the client may be gone already (Ctrl-C): nothing to undo
                pass


def _ready(client: Any, batch: BatchConfig) -> None:
    """At least one worker, and every worker can import the optimiser (imports done before
    the first task, so its time is the optimisation's).

    Raises:
        HandSuiteError: no worker joined within ``connect_timeout``, or a worker cannot
            import hand_suite's optimiser (not installed there).
    """
    where = batch.scheduler or "the local cluster"
    try:
        client.wait_for_workers(1, timeout=batch.connect_timeout)
    except (TimeoutError, OSError) as e:
        raise HandSuiteError(f"no Dask worker joined {where} within "
                             f"{batch.connect_timeout:g} s ({type(e).__name__})") from e
    try:
        client.run(_warm_worker)
    except Exception as e:  # ModuleNotFoundError on the worker, unpickling errors, ...
        raise HandSuiteError(f"the workers of {where} cannot load hand_suite's optimiser "
                             f"({type(e).__name__}: {e}); install the same hand_suite on "
                             f"every worker") from e


def run_archive(archive_dir: str | Path, out_dir: str | Path | None, config: PhysCapConfig,
                batch: BatchConfig | None = None, *,
                default_object: ObjectProperties | None = None,
                archive: ArchiveConfig | None = None, optimiser: str = "") -> BatchResult:
    """:func:`list_archive` then :func:`run_batch` (what ``hand-suite physcap run`` does).

    Raises:
        InputError: ``archive_dir`` is neither a directory nor a capture, holds no capture,
            or is ``out_dir``.
    """
    if out_dir is not None and Path(out_dir).resolve() == Path(archive_dir).resolve():
        raise InputError("the output folder must not be the archive itself")
    entries = list_archive(archive_dir, default_object, archive)
    if not entries:
        raise InputError(f"{archive_dir} holds no capture (*.npz, bag folders, *.mcap)")
    return run_batch(entries, config, out_dir, batch, default_object=default_object,
                     archive=archive, optimiser=optimiser)


def measure_dask_speedup(captures: Sequence[Capture | str | Path], config: PhysCapConfig,
                         quick: bool = False, workdir: str | Path | None = None,
                         optimiser: str = "") -> dict[str, Any]:
    """Wall time of one batch on a local cluster of 1 worker process against 2 (same
    captures, same config; cluster start-up and imports excluded), and whether both gave
    identical results.

    Args:
        captures: Capture objects (saved as npz in a temporary archive) or capture files.
        config: the optimisation settings (the bench's).
        quick: use at most 2 captures (else all).
        workdir: folder for the temporary archive (default: a temporary directory).

    Returns:
        ``dask_1w_s``, ``dask_2w_s`` [s], ``dask_speedup_2w`` (1-worker time / 2-worker
        time), ``dask_identical`` (bool), ``dask_captures``, ``dask_failed`` (names),
        ``dask_1w_task_s`` / ``dask_2w_task_s`` (sum of the tasks' own wall times [s]) and
        ``dask_task_time_ratio`` (their ratio: 1 = each of 2 workers as fast as a lone one, 2
        = the two shared one worker's CPU, e.g. on a loaded host), ``load_avg_1min`` (this
        machine's load when the measurement began).
    """
    import os
    import shutil
    import tempfile

    from hand_control.physcap.capture import save_capture_npz
    from hand_control.physcap.output import results_equal

    items = list(captures)[: 2 if quick else None]
    if len(items) < 2:
        raise InputError("measure_dask_speedup needs at least 2 captures")
    tmp = Path(tempfile.mkdtemp(prefix="physcap_dask_", dir=workdir))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    try:
        arch = tmp / "archive"
        arch.mkdir()
        for i, c in enumerate(items):
            if isinstance(c, Capture):
                save_capture_npz(c, arch / f"{i:02d}_{c.name}.npz")
            else:
                shutil.copy(c, arch / Path(c).name)
        entries = list_archive(arch)
        times: dict[int, float] = {}
        results: dict[int, BatchResult] = {}
        for n in (1, 2):
            with dask_client(n) as client:
                client.run(_warm_worker)
                jobs = {e.name: CaptureJob.from_entry(e, config, optimiser=optimiser)
                        for e in entries if e.ok}
                t0 = time.perf_counter()
                futs = client.map(_dask_task, list(jobs.values()), pure=False)
                outs = client.gather(futs)
                times[n] = time.perf_counter() - t0
                results[n] = BatchResult(list(outs), times[n], f"local {n}")
        task_s = {n: sum(o.seconds for o in results[n].outcomes) for n in (1, 2)}
        a = {o.name: o for o in results[1].outcomes}
        identical = all(o.ok and a[o.name].ok and not results_equal(a[o.name].result,
                                                                  o.result)
                        for o in results[2].outcomes)
        return {"dask_1w_s": times[1], "dask_2w_s": times[2],
                "dask_speedup_2w": times[1] / times[2] if times[2] > 0 else None,
                "dask_identical": bool(identical), "dask_captures": len(entries),
                "dask_failed": [o.name for o in results[2].outcomes if not o.ok],
                "dask_1w_task_s": task_s[1], "dask_2w_task_s": task_s[2],
                "dask_task_time_ratio": task_s[2] / task_s[1] if task_s[1] > 0 else None,
                "load_avg_1min": load}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
