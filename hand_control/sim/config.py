"""Configuration of the MuJoCo simulation (frozen, validated; filled from YAML or ROS params)."""

from __future__ import annotations

from dataclasses import dataclass

from hand_capture.config import param, validate

__all__ = ["SimConfig", "SimNodeConfig"]


@dataclass(frozen=True)
class SimConfig:
    """The simulated world and how it is stepped.

    The scene itself (objects, masses, frictions) comes from a scenario file
    (``config/scenarios/*.yaml``); this holds what does not depend on the scene.
    """

    timestep: float = param(
        0.001, "physics step [s]; the dissertation's controller runs at 1 ms (ch. III.7)",
        lo=1e-5, hi=0.01)
    integrator: str = param(
        "implicitfast", "MuJoCo integrator (implicitfast integrates the servo damping "
        "implicitly)", choices=("Euler", "RK4", "implicit", "implicitfast"))
    hand_gravcomp: bool = param(
        True, "cancel gravity on the hand bodies inside MuJoCo (tau_gravity of eq. III.19); "
        "the controller then adds no gravity term of its own")
    on_instability: str = param(
        "raise", "what a divergence (MuJoCo warning BADQACC/BADQPOS/BADQVEL/BADCTRL, or a "
        "non-finite state) does: 'raise' SimulationError, or 'reset' the episode to its "
        "initial state deliberately (counted); never MuJoCo's silent auto-reset",
        choices=("raise", "reset"))
    max_joint_speed: float = param(
        200.0, "a hand joint faster than this [rad/s or m/s] counts as a divergence", lo=1.0)
    real_time: bool = param(
        False, "pace stepping to the wall clock (True) or step as fast as possible (False)")
    real_time_factor: float = param(
        1.0, "simulated seconds per wall second when real_time is set", lo=0.01, hi=100.0)
    command_timeout: float = param(
        0.1, "after this long without a joint command [s, sim time] the servos hold the "
        "last position targets and the feed-forward efforts are handled by timeout_effort",
        lo=0.0)
    timeout_effort: str = param(
        "zero", "feed-forward efforts after a command timeout: 'zero' (servo-only hold) or "
        "'hold' (keep the last efforts)", choices=("zero", "hold"))
    contact_margin_report: float = param(
        0.0, "report contacts whose distance is below this [m] (0 = touching/penetrating)",
        lo=0.0, hi=0.01)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class SimNodeConfig:
    """The sim node: which scenario's world, how often it publishes, whether it owns time."""

    scenario: str = param("lift_box", "scenario file (config/scenarios/<name>.yaml) whose "
                          "object, mass and friction make the world")
    steps_per_tick: int = param(
        2, "physics steps per timer tick; states, object pose and contacts are published "
        "once per tick (2 x 1 ms = 500 Hz)", lo=1, hi=1000)
    publish_clock: bool = param(
        True, "publish /clock with the simulation time (the sim owns time; run the other "
        "nodes with use_sim_time)")
    frame_id: str = param("world", "frame of every published pose, point and force")

    def __post_init__(self) -> None:
        validate(self)
