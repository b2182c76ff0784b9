"""``hand-suite bench fuzz``: hostile messages pushed through every node's input validation and
the core paths behind it; failures must be 0.

Two generators, both seeded (the same cases every run):

* **hostile** (what the validation layer was built against, issue #20): NaN, +-Inf, 1e6,
  1e308, empty, mismatched and duplicated arrays, unknown names, bad enumerations, touches far
  off the surface, future stamps;
* **bit flips** (a generator the layer was *not* built from): valid messages with one random bit
  flipped in one float64 field (sign, exponent or mantissa), the damage a bad link or a bad
  bag does.

Per message type (the node-boundary functions of :mod:`hand_capture.validate`, exactly what the
nodes call): cases, accepted, rejected, *failures* (an accepted message that breaks the type's
invariants: a non-finite value, a value outside its range, a bad enumeration; or an exception
other than InputError), and messages per second. Baseline, same run: the plain conversion the
nodes did before the layer (``pose_from_msg``, ``np.asarray`` of the arrays), as
``overhead`` = validation time / plain time.

Behind the validation, the core paths (cases and failures): the servo bridge's write path on
the emulated bus (goals finite and within the servo limits, the bridge still follows a valid
pose afterwards), the simulated world's command path (efforts within the actuator limits), the
grasp-phase detector (a grasp and its release still detected around injected stamps) and the
touch encoder behind its node boundary (finite, bounded poses).
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_capture.errors import InputError
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_NAMES, joint_limits_dict
from hand_capture.posemsg import pose_from_msg
from hand_capture.validate import (
    DEFAULT_LIMITS,
    joint_bounds,
    validate_contacts,
    validate_grasp_phase,
    validate_hand_pose_msg,
    validate_joint_command,
    validate_joint_state,
    validate_pose,
    validate_touch_frame,
    validate_twist,
)

NAMES = list(ARTICULATED_JOINTS)
_SPECIAL = np.array([np.nan, np.inf, -np.inf, 1e6, -1e6, 1e308, -1e308, 3.0])
_LIM = np.array([joint_limits_dict()[n] for n in NAMES])
L = DEFAULT_LIMITS


# ---------------------------------------------------------------------------- generators
def _value(rng: np.random.Generator) -> float:
    r = rng.random()
    if r < 0.3:
        return float(rng.choice(_SPECIAL))
    if r < 0.5:
        return float(rng.normal() * 10.0 ** int(rng.integers(-3, 8)))
    return float(rng.uniform(-0.3, 1.0))


def _flip(x: float, rng: np.random.Generator) -> float:
    """``x`` with one random bit of its float64 representation flipped."""
    (u,) = struct.unpack("<Q", struct.pack("<d", x))
    return struct.unpack("<d", struct.pack("<Q", u ^ (1 << int(rng.integers(0, 64)))))[0]


def _valid_pose_values(rng: np.random.Generator) -> list[float]:
    return [float(v) for v in rng.uniform(_LIM[:, 0], _LIM[:, 1])]


def _hand_pose(vals, names=NAMES, status=1, pos=(0.0, 0.0, 0.4), quat=(0.0, 0.0, 0.0, 1.0),
               side=0, conf=1.0) -> SimpleNamespace:
    p = SimpleNamespace(x=pos[0], y=pos[1], z=pos[2])
    o = SimpleNamespace(x=quat[0], y=quat[1], z=quat[2], w=quat[3])
    return SimpleNamespace(joint_names=list(names), positions=list(vals), status=status,
                           handedness=side, confidence=conf,
                           wrist_pose=SimpleNamespace(position=p, orientation=o))


def _names(rng: np.random.Generator, vocab: list[str], n: int) -> list[str]:
    names = list(vocab[:n])
    r = rng.random()
    if r < 0.15 and names:
        names[-1] = names[0]  # duplicated
    elif r < 0.25:
        names.append("bogus")
    return names


def gen_hand_pose(rng: np.random.Generator, flip: bool) -> SimpleNamespace:
    vals = _valid_pose_values(rng)
    pos, quat = [0.0, 0.0, 0.4], [0.0, 0.0, 0.0, 1.0]
    if flip:
        fields = vals + pos + quat
        k = int(rng.integers(0, len(fields)))
        fields[k] = _flip(fields[k], rng)
        return _hand_pose(fields[:21], pos=fields[21:24], quat=fields[24:])
    r = rng.random()
    if r < 0.1:
        return _hand_pose([], names=[])
    if r < 0.2:
        return _hand_pose(vals, status=int(rng.integers(5, 256)))
    if r < 0.3:
        return _hand_pose(vals, names=_names(rng, NAMES, 21))
    for k in rng.choice(21, size=int(rng.integers(1, 4)), replace=False):
        vals[k] = _value(rng)
    if rng.random() < 0.2:
        pos[int(rng.integers(0, 3))] = _value(rng)
    if rng.random() < 0.2:
        quat[int(rng.integers(0, 4))] = _value(rng)
    return _hand_pose(vals, pos=pos, quat=quat)


def _arrays(rng: np.random.Generator, n: int, flip: bool, valid: Callable[[], list[float]]
            ) -> list[float]:
    vals = valid()
    if flip:
        k = int(rng.integers(0, n))
        vals[k] = _flip(vals[k], rng)
        return vals
    m = n + (int(rng.integers(-1, 2)) if rng.random() < 0.2 else 0)
    vals = (vals + [0.0])[:max(m, 0)]
    for k in range(len(vals)):
        if rng.random() < 0.03:
            vals[k] = _value(rng)
    return vals


def gen_joint_state(rng: np.random.Generator, flip: bool) -> tuple:
    names = list(JOINT_NAMES) if flip else _names(rng, list(JOINT_NAMES), 27)
    q = [0.0] * 6 + _valid_pose_values(rng)
    pos = _arrays(rng, 27, flip, lambda: list(q))
    vel = _arrays(rng, 27, flip and rng.random() < 0.5, lambda: [0.1] * 27)
    return names, pos, vel


def gen_joint_command(rng: np.random.Generator, flip: bool) -> tuple:
    names, pos, _ = gen_joint_state(rng, flip)
    eff = _arrays(rng, 27, flip, lambda: [0.5] * 27)
    return names, pos, eff


def gen_pose(rng: np.random.Generator, flip: bool) -> tuple:
    p, o = [0.1, -0.2, 0.3], [0.0, 0.0, 0.6, 0.8]
    f = p + o
    if flip:
        k = int(rng.integers(0, 7))
        f[k] = _flip(f[k], rng)
    else:
        for k in rng.choice(7, size=int(rng.integers(1, 3)), replace=False):
            f[k] = _value(rng)
    return f[:3], f[3:]


def gen_twist(rng: np.random.Generator, flip: bool) -> tuple:
    f = [0.1, 0.0, -0.1, 0.5, 0.0, 1.0]
    k = int(rng.integers(0, 6))
    f[k] = _flip(f[k], rng) if flip else _value(rng) * 100
    return f[:3], f[3:]


def gen_contacts(rng: np.random.Generator, flip: bool) -> tuple:
    k = int(rng.integers(1, 5))
    pts = rng.uniform(-0.1, 0.1, (k, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (k, 1))
    frc = rng.uniform(0.0, 5.0, (k, 3))
    mu = np.full(k, 0.8)
    arrs = [pts, nrm, frc, mu]
    a = arrs[int(rng.integers(0, 4))].reshape(-1)
    i = int(rng.integers(0, a.size))
    a[i] = _flip(float(a[i]), rng) if flip else _value(rng) * 1e3
    return pts, nrm, frc, mu


def gen_touch(rng: np.random.Generator, flip: bool) -> tuple:
    w, h = 0.197, 0.148
    n = int(rng.integers(1, 6))
    c = np.array([rng.uniform(0.05, 0.15), rng.uniform(0.04, 0.1)])
    pos = (c + rng.uniform(-0.04, 0.04, (n, 2))).tolist()
    ids = list(range(n))
    if flip:
        k = int(rng.integers(0, n))
        pos[k][int(rng.integers(0, 2))] = _flip(pos[k][0], rng)
    else:
        r = rng.random()
        if r < 0.2:
            w = _value(rng)
        elif r < 0.3 and n > 1:
            ids[-1] = ids[0]
        else:
            pos[int(rng.integers(0, n))][int(rng.integers(0, 2))] = _value(rng)
    return ids, pos, [True] * n, w, h


def gen_phase(rng: np.random.Generator, flip: bool) -> tuple:
    v = int(rng.integers(0, 4))
    return (v ^ (1 << int(rng.integers(0, 8))),) if flip or rng.random() < 0.5 else (v,)


# ------------------------------------------------------------------------ invariants
def _ok_joints(names, pos) -> bool:
    lo, hi = joint_bounds(tuple(names))
    return bool(np.isfinite(pos).all() and ((pos >= lo) & (pos <= hi)).all()
                and len(set(names)) == len(names))


def inv_hand_pose(msg, q) -> bool:
    lo, hi = joint_bounds(tuple(JOINT_NAMES[6:]))
    return bool(q.shape == (27,) and np.isfinite(q).all() and msg.status <= 4
                and ((q[6:] >= lo) & (q[6:] <= hi)).all()
                and (np.abs(q[:3]) <= L.max_position).all())


def inv_joint_state(args, out) -> bool:
    names, pos, vel = out
    return _ok_joints(names, pos) and (vel is None or bool(
        np.isfinite(vel).all() and (np.abs(vel) <= L.max_velocity).all()))


def inv_joint_command(args, out) -> bool:
    names, pos, eff = out
    return (not len(pos) or _ok_joints(names, pos)) and bool(
        np.isfinite(eff).all() and (np.abs(eff) <= L.max_effort).all())


def inv_pose(args, out) -> bool:
    p, q = out
    return bool(np.isfinite(p).all() and (np.abs(p) <= L.max_position).all()
                and abs(np.linalg.norm(q) - 1.0) < 1e-9)


def inv_twist(args, out) -> bool:
    v, w = out
    return bool(np.isfinite(v).all() and np.isfinite(w).all()
                and (np.abs(v) <= L.max_linear_speed).all()
                and (np.abs(w) <= L.max_angular_speed).all())


def inv_contacts(args, out) -> bool:
    return all(bool(np.isfinite(a).all()) for a in out) and bool(
        (np.linalg.norm(out[2], axis=1) <= L.max_contact_force).all())


def inv_touch(args, pos) -> bool:
    w, h = args[3], args[4]
    m = L.touch_margin
    return bool(np.isfinite(pos).all() and (pos[:, 0] >= -m * w).all()
                and (pos[:, 0] <= (1 + m) * w).all() and (pos[:, 1] >= -m * h).all()
                and (pos[:, 1] <= (1 + m) * h).all())


def inv_phase(args, v) -> bool:
    return 0 <= v <= 3


def _plain_hand_pose(msg) -> object:
    try:
        return pose_from_msg(msg)
    except InputError:
        return None


def _plain_arrays(*args) -> object:
    return [np.asarray(a, dtype=float) for a in args if not isinstance(a, str)]


#: name -> (generator, validation as the node calls it, invariant, plain conversion)
TYPES: dict[str, tuple] = {
    "HandPose": (gen_hand_pose, lambda m: validate_hand_pose_msg(m), inv_hand_pose,
                 _plain_hand_pose),
    "JointState": (gen_joint_state, lambda a: validate_joint_state(*a), inv_joint_state,
                   lambda a: _plain_arrays(a[1], a[2])),
    "JointCommand": (gen_joint_command, lambda a: validate_joint_command(a[0], a[1], (), a[2]),
                     inv_joint_command, lambda a: _plain_arrays(a[1], a[2])),
    "Pose": (gen_pose, lambda a: validate_pose(*a), inv_pose, lambda a: _plain_arrays(*a)),
    "Twist": (gen_twist, lambda a: validate_twist(*a), inv_twist,
              lambda a: _plain_arrays(*a)),
    "ContactArray": (gen_contacts, lambda a: validate_contacts(*a), inv_contacts,
                     lambda a: _plain_arrays(*a)),
    "TouchFrame": (gen_touch, lambda a: validate_touch_frame(*a), inv_touch,
                   lambda a: _plain_arrays(a[1])),
    "GraspPhase": (gen_phase, lambda a: validate_grasp_phase(*a), inv_phase,
                   lambda a: int(a[0])),
}


def fuzz_type(name: str, n: int, flip: bool, seed: int) -> dict[str, Any]:
    """Push ``n`` generated messages of one type through its validation; figures."""
    gen, check, inv, plain = TYPES[name]
    rng = np.random.default_rng(seed)
    msgs = [gen(rng, flip) for _ in range(n)]
    accepted = failures = 0
    examples: list[str] = []
    t0 = time.perf_counter()
    outs = []
    for m in msgs:
        try:
            outs.append(check(m))
        except InputError:
            outs.append(None)
        except Exception as e:  # anything but a clean rejection is a failure
            outs.append(e)
    dt = time.perf_counter() - t0
    with np.errstate(all="ignore"):  # the plain conversion overflows on 1e308 quaternions
        t0 = time.perf_counter()
        for m in msgs:
            plain(m)
        dt_plain = time.perf_counter() - t0
    for m, out in zip(msgs, outs, strict=True):
        if out is None:
            continue
        if isinstance(out, Exception) or not inv(m, out):
            failures += 1
            if len(examples) < 3:
                examples.append(f"{name}: {out!r}"[:200])
        else:
            accepted += 1
    return {"cases": n, "accepted": accepted, "failures": failures, "seconds": dt,
            "plain_seconds": dt_plain, "examples": examples}


# -------------------------------------------------------------------------- core paths
def fuzz_bridge(n: int, seed: int) -> tuple[int, int]:
    """Hostile poses straight into the bridge core on the emulated bus: goals finite and
    within the servo limits; the bridge follows a valid pose at the end."""
    from hand_control.dynamixel import control_table as ct
    from hand_control.dynamixel.bridge import BridgeConfig, ServoBridge

    clock = [100.0]
    quiet = logging.getLogger("hand_suite.bench.fuzz.bridge")
    quiet.setLevel(logging.ERROR)  # thousands of rejections: counted here, not printed
    b = ServoBridge(BridgeConfig(servo_map="generic_3dof", packet_timeout_ms=100.0,
                                 filter_cutoff_hz=0.0), clock=lambda: clock[0], logger=quiet)
    rng = np.random.default_rng(seed)
    failures = 0
    with b:
        for _ in range(n):
            msg = gen_hand_pose(rng, rng.random() < 0.5)
            try:
                b.handle_pose(msg.joint_names, msg.positions, now=clock[0])
            except Exception:  # the core must reject, not raise
                failures += 1
            clock[0] += 0.005
            b.step()
            last = b.limiter.last
            if not (np.isfinite(last).all() and ((last >= b.limiter.lo)
                                                 & (last <= b.limiter.hi)).all()):
                failures += 1
        good = [0.0] * 21
        good[NAMES.index("index_pip_flex")] = 0.9
        for _ in range(200):
            b.handle_pose(NAMES, good, now=clock[0])
            clock[0] += 0.005
            b.step()
        want = np.clip(np.rint(b.retarget.from_named(NAMES, good) * ct.TICKS_PER_RAD
                               + ct.POSITION_CENTER), b.limiter.lo, b.limiter.hi)
        got = np.array([b.emulator.value(i, "goal_position") for i in b.ids])
        failures += int(np.abs(got - want).max() > 1) + int(b.skipped_writes > 0)
    return n, failures


def fuzz_world(n: int, seed: int) -> tuple[int, int]:
    """Hostile joint commands straight into the simulated world's command path: efforts
    stay within the actuator limits; the world steps without diverging afterwards."""
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import load_scenario

    w = LockstepRunner(load_scenario("lift_box")).world
    rng = np.random.default_rng(seed)
    failures = 0
    for _ in range(n):
        names, pos, eff = gen_joint_command(rng, rng.random() < 0.5)
        try:
            w.command_by_name(names, pos[:len(names)] if len(pos) >= len(names) else pos,
                              eff[:len(names)] if len(eff) >= len(names) else eff)
        except InputError:
            pass
        except Exception:
            failures += 1
        if not ((w.effort >= w.effort_lo) & (w.effort <= w.effort_hi)).all():
            failures += 1
    w.set_command(w.hand_state()[0], np.zeros(w.n_hand))
    try:
        w.step(200)
    except Exception:
        failures += 1
    return n, failures


def fuzz_phases(n: int, seed: int) -> tuple[int, int]:
    """A grasp with 1-3 hand poses of a random stamp injected anywhere: the grasp and its
    release must still be detected."""
    from hand_capture.model import JOINT_INDEX, HandModel, rest_pose, root_rotation_matrix
    from hand_control.teleop.phases import GraspPhaseDetector, Phase

    flex = [j for j in JOINT_INDEX if j.endswith(("_mcp_flex", "_pip_flex", "_dip_flex"))
            and not j.startswith("thumb")]

    def pose(x: float, close: float) -> np.ndarray:
        q = rest_pose().copy()
        q[JOINT_INDEX["root_tx"]] = x
        for j in flex:
            q[JOINT_INDEX[j]] = close
        return q

    m = HandModel()
    kp0 = m.forward(pose(0.0, 0.0)).joint_positions
    obj = np.eye(4)
    obj[:3, 3] = kp0[[0, 5, 9, 13, 17]].mean(axis=0)
    qs = [pose(x, 0.0) for x in np.linspace(0.5, 0.0, 30)]
    qs += [pose(0.0, c) for c in list(np.linspace(0.0, 0.8, 10)) + [0.8] * 30]
    qs += [pose(0.0, c) for c in list(np.linspace(0.8, 0.0, 8)) + [0.0] * 25]
    frames = []
    for q in qs:
        wrist = np.eye(4)
        wrist[:3, :3] = root_rotation_matrix(q[3:6])
        wrist[:3, 3] = q[:3]
        frames.append((m.forward(q).joint_positions, wrist))
    rng = np.random.default_rng(seed)
    failures = 0
    for _ in range(n):
        at = int(rng.integers(0, len(frames)))
        stamp = float(rng.choice([4e9, 1e9, -1.0, rng.uniform(-1e12, 1e12)]))
        det = GraspPhaseDetector()
        seen = set()
        for k, (kp, wrist) in enumerate(frames):
            if k == at:
                for _ in range(int(rng.integers(1, 4))):
                    det.update(stamp, kp, wrist, obj)
            seen.add(det.update(k / 30, kp, wrist, obj).phase)
        failures += int(not {Phase.MANIPULATION, Phase.RELEASING} <= seen)
    return n, failures


def fuzz_touch(n: int, seed: int) -> tuple[int, int]:
    """Hostile touch frames through the touch encoder node's boundary into the encoder:
    every pose finite and bounded."""
    from hand_capture.nodes.touch_encoder import frame_from_msg
    from hand_capture.touch.encoder import TouchEncoder, TouchEncoderConfig

    enc = TouchEncoder(TouchEncoderConfig())
    rng = np.random.default_rng(seed)
    failures = 0
    for k in range(n):
        ids, pos, flags, w, h = gen_touch(rng, rng.random() < 0.5)
        msg = SimpleNamespace(
            header=SimpleNamespace(stamp=SimpleNamespace(sec=k, nanosec=0), frame_id="s"),
            width=w, height=h,
            points=[SimpleNamespace(session_id=1000 * k + i, x=p[0], y=p[1], in_contact=c)
                    for i, p, c in zip(ids, pos, flags, strict=True)])
        try:
            res = enc.process(frame_from_msg(msg))
        except InputError:
            continue
        except Exception:
            failures += 1
            continue
        if res is not None and not (np.isfinite(res.pose).all()
                                    and np.abs(res.pose[6:]).max() < 50.0):
            failures += 1
    return n, failures


# --------------------------------------------------------------------------------- run
def run(quick: bool = False, scale: float = 1.0, smoke: bool = False) -> dict[str, Any]:
    """The bench (module docstring); ``scale`` shrinks every count (``smoke``: 0.05)."""
    if smoke:
        scale = min(scale, 0.05)
    n = max(int((2000 if quick else 20000) * scale), 10)
    rows, figures = [], {}
    total_cases = total_fail = 0
    total_s = plain_s = 0.0
    examples: list[str] = []
    for gi, (gen_name, flip) in enumerate((("hostile", False), ("bitflip", True))):
        g_fail = 0
        for ti, name in enumerate(TYPES):
            r = fuzz_type(name, n, flip, seed=1000 * gi + ti)
            total_cases += r["cases"]
            total_fail += r["failures"]
            g_fail += r["failures"]
            total_s += r["seconds"]
            plain_s += r["plain_seconds"]
            examples += r["examples"]
            rate = r["cases"] / max(r["seconds"], 1e-12)
            overhead = r["seconds"] / max(r["plain_seconds"], 1e-12)
            rows.append([gen_name, name, r["cases"], r["accepted"],
                         r["cases"] - r["accepted"] - r["failures"], r["failures"], rate,
                         overhead])
            if not flip:
                figures[f"msgs_per_s_{name}"] = rate
        figures[f"failures_{gen_name}"] = g_fail
    print_table("Input validation of every node (hand_capture.validate), seeded generators",
                ["generator", "message", "cases", "accepted", "rejected", "failures",
                 "msgs/s", "overhead"], rows)
    print("overhead = validation time / plain conversion time (pose_from_msg, np.asarray), "
          "same messages, same run")
    core_n = {k: max(int(v * (1 if quick else 10) * scale), 2) for k, v in
              {"bridge": 150, "world": 300, "phases": 10, "touch": 300}.items()}
    core_rows = []
    for name, fn in (("servo bridge write path (emulated bus)", fuzz_bridge),
                     ("sim world command path", fuzz_world),
                     ("grasp-phase detector (injected stamps)", fuzz_phases),
                     ("touch encoder behind its node boundary", fuzz_touch)):
        key = name.split()[0] if not name.startswith("servo") else "bridge"
        key = {"sim": "world", "grasp-phase": "phases"}.get(key, key)
        t0 = time.perf_counter()
        cases, fails = fn(core_n[key], seed=7)
        core_rows.append([name, cases, fails, time.perf_counter() - t0])
        total_cases += cases
        total_fail += fails
        figures[f"failures_core_{key}"] = fails
    print_table("Core paths behind the validation", ["path", "cases", "failures", "seconds"],
                core_rows)
    for e in examples[:5]:
        print("failure:", e)
    validated = 2 * n * len(TYPES)
    figures.update({
        "cases": total_cases, "failures": total_fail,
        "msgs_per_s": validated / max(total_s, 1e-12),
        "plain_msgs_per_s": validated / max(plain_s, 1e-12),
        "overhead_ratio": total_s / max(plain_s, 1e-12),
        "message_types": len(TYPES),
    })
    return figures
