"""``pink_cbf``: PUMA's motion followed by a QP differential IK with control-barrier functions.

Each control step PUMA's task acceleration ẍ_d becomes the hand's target twist for one period,
tracked by pink's frame task; the body spheres against the obstacles and the ground, and the
joint position and velocity limits, are constraints of the same QP (see :mod:`.controller`).
Registered as a tamedpuma method through the entry point ``tamedpuma.methods`` (pyproject.toml).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tamedpuma.methods import MethodPlugin


@dataclass(frozen=True)
class PinkCbfSettings:
    """The options of ``method=pink_cbf`` (``conf/method/pink_cbf.yaml``), units in brackets."""

    task: str | None = None         # whose PUMA model drives the hand (conf: ${task.name})
    checkpoint: str | None = None   # a second-order puma.pt; null: the best model at hand
    model: str = "auto"             # with checkpoint null: auto | real | shipped
    solver: str = "daqp"            # the qpsolvers backend
    position_cost: float = 1.0      # frame task [cost/m]
    orientation_cost: float = 0.5   # frame task [cost/rad]
    posture_cost: float = 0.001     # posture task towards the start configuration [cost/rad]
    damping: float = 1e-6           # Tikhonov regularization of the QP [cost²/rad]
    barrier_gain: float = 5.0       # γ [1/s] of the class-K term: ḣ ≥ −γ h
    d_min: float = 0.02             # [m] clearance every body sphere keeps from every obstacle
    activation_distance: float = 0.5  # [m] pairs farther apart than this are left out of the QP
    ground_height: float | None = 0.01  # [m] the spheres keep above this plane (null: none)
    limit_margin: float = 0.01      # [rad] the joint limits sit this far inside the robot's
    limit_gain: float = 0.5         # pink's configuration-limit gain in (0, 1]
    speed_headroom: float = 0.01    # the velocity limit is (1 − this) q̇_max

    def __post_init__(self):
        for key in ("position_cost", "barrier_gain", "activation_distance"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)!r}")
        for key in ("orientation_cost", "posture_cost", "damping", "d_min", "limit_margin"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"{key} must be >= 0, got {getattr(self, key)!r}")
        if not 0 < self.limit_gain <= 1:
            raise ValueError(f"limit_gain must be in (0, 1], got {self.limit_gain!r}")
        if not 0 <= self.speed_headroom < 1:
            raise ValueError(f"speed_headroom must be in [0, 1), got "
                             f"{self.speed_headroom!r}")


def make(settings: PinkCbfSettings, kinematics):
    """The controller of its settings (the sweep passes the resolved ``checkpoint``)."""
    from pink_cbf.controller import PinkCbf
    from tamedpuma.methods import puma_task

    return PinkCbf(kinematics, puma_task(settings), settings)


PLUGIN = MethodPlugin(name="pink_cbf", make=make, settings=PinkCbfSettings,
                      config_dir=Path(__file__).parent / "conf")
