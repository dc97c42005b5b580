"""Vanilla PUMA (method.md §4): the network's task acceleration pulled back to the joints.

    q̈ = J⁺(ẍ_d − J̇q̇) + N q̈_null,   ẍ_d = f_θ^T(x_ee, ẋ_ee)          [rad/s²]

with a damped pseudo-inverse and the "elbow up" null-space objective. No obstacle avoidance: it is
the paper's reference for paths (path difference 0) and its unsafe baseline.
Scalars: ``task_acc_norm`` ‖ẍ_d‖ and ``joint_acc_norm`` ‖q̈‖.
"""

from __future__ import annotations

from tamedpuma.methods._settings import PumaSettings
from tamedpuma.methods._tamed import PumaController, pulled_puma

__all__ = ["SETTINGS", "PumaController", "PumaSettings", "make"]

#: the settings ``make`` takes; their defaults are what ``method=puma`` composes (tested)
SETTINGS = PumaSettings


def make(settings: PumaSettings, kinematics) -> PumaController:
    return pulled_puma(settings, kinematics)
