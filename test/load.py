"""CPU load for tests: N busy processes for a bounded time, that stop by themselves.

Run the suite under load (the tests must pass on a loaded machine)::

    HAND_SUITE_TEST_LOAD=2 python -m pytest -q test/      # conftest starts 2 burners
    # (they stop with the session, or after HAND_SUITE_TEST_LOAD_SECONDS, default 3600)

or by hand, beside anything else::

    python test/load.py -n 2 -t 600      # 2 burners for at most 600 s (Ctrl-C stops them)

Each burner spins a tight arithmetic loop until its deadline, until the process that started
it dies (it watches its parent), or until it is terminated. :class:`CpuLoad` is the same as a
context manager, for conftest and scripts.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import signal
import sys
import time


def _burn(deadline: float, parent: int) -> None:
    """Spin until ``deadline`` (time.monotonic) or until ``parent`` is gone."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    x = 0
    while True:
        for _ in range(200_000):  # ~10 ms of work between checks
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF
        if time.monotonic() >= deadline or os.getppid() != parent:
            return


class CpuLoad:
    """``n`` CPU-burning processes for at most ``seconds`` [s]; stop() or leaving the ``with``
    block ends them earlier."""

    def __init__(self, n: int, seconds: float = 900.0) -> None:
        if n < 0:
            raise ValueError(f"number of burners must be >= 0, got {n}")
        if not 0.0 < seconds <= 24 * 3600.0:
            raise ValueError(f"seconds must be in (0, 86400], got {seconds}")
        self.n, self.seconds = n, seconds
        self.procs: list[mp.Process] = []

    def start(self) -> CpuLoad:
        deadline = time.monotonic() + self.seconds  # monotonic is system-wide on Linux
        ctx = mp.get_context("fork")
        for _ in range(self.n):
            p = ctx.Process(target=_burn, args=(deadline, os.getpid()), daemon=True)
            p.start()
            self.procs.append(p)
        return self

    def alive(self) -> int:
        """How many burners still run."""
        return sum(p.is_alive() for p in self.procs)

    def stop(self) -> None:
        for p in self.procs:
            if p.is_alive():
                p.terminate()
        for p in self.procs:
            p.join(timeout=5.0)
        self.procs.clear()

    def __enter__(self) -> CpuLoad:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2, help="number of burning processes (default 2)")
    ap.add_argument("-t", type=float, default=600.0,
                    help="stop after this many seconds (default 600)")
    a = ap.parse_args(argv)
    load = CpuLoad(a.n, a.t).start()
    print(f"{a.n} burner(s) for at most {a.t:.0f} s (pids {[p.pid for p in load.procs]})",
          flush=True)
    try:
        for p in load.procs:
            p.join()
    except KeyboardInterrupt:
        pass
    finally:
        load.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
