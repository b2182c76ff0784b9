"""Rewrite requirements.txt from what is installed in the running venv (after an upgrade).

Only distributions pip installed (``*.dist-info``) are pinned: the ROS wheels also carry inner
``*.egg-info`` folders (e.g. ``action_msgs``) that are not installable names, and hand_suite /
hand_msgs are built from this repository.

    .venv/bin/python scripts/pin_requirements.py
"""

from __future__ import annotations

from importlib.metadata import distributions
from pathlib import Path

REQ = Path(__file__).resolve().parents[1] / "requirements.txt"
OWN = {"hand-suite", "hand-msgs"}
NODEPS = Path(__file__).resolve().parents[1] / "requirements-nodeps.txt"


def _nodeps() -> set[str]:
    """Names pinned in requirements-nodeps.txt (installed with --no-deps, kept out of here)."""
    lines = NODEPS.read_text().splitlines() if NODEPS.exists() else []
    return {ln.split("==")[0].strip().lower() for ln in lines if ln and not ln.startswith("#")}


def main() -> None:
    pins: dict[str, str] = {}
    for dist in distributions():
        if Path(str(dist._path)).suffix != ".dist-info":
            continue
        name = dist.metadata["Name"].lower().replace("_", "-")
        if name not in OWN and name not in _nodeps():
            pins[name] = dist.version
    header = [ln for ln in REQ.read_text().splitlines() if ln.startswith("#")]
    REQ.write_text("\n".join(header + [f"{n}=={v}" for n, v in sorted(pins.items())]) + "\n")
    print(f"pinned {len(pins)} distributions in {REQ}")


if __name__ == "__main__":
    main()
