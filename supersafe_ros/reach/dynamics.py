"""Control-affine models for reachability, behind one small interface.

A model gives its state layout, a finite set of extreme controls (enough for
Hamiltonians linear in u), its exact flow under a constant control, and the
control that maximises dV/dt for a given gradient (the optimal avoid control).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .grid import wrap_angle


@dataclass(frozen=True)
class DubinsCar:
    """x' = v cos(theta), y' = v sin(theta), theta' = u, |u| <= omega_max.

    The Hamiltonian max_u dV/dx . f is linear in u, so the optimal avoid control
    is bang-bang: u* = omega_max sign(dV/dtheta).
    """

    speed: float = 3.0
    omega_max: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.speed) and self.speed > 0):
            raise ValueError(f'speed must be positive and finite, got {self.speed}')
        if not (np.isfinite(self.omega_max) and self.omega_max >= 0):
            raise ValueError(f'omega_max must be >= 0 and finite, got {self.omega_max}')

    def params(self) -> dict:
        return {'model': 'dubins', 'speed': float(self.speed), 'omega_max': float(self.omega_max)}

    def extreme_controls(self) -> np.ndarray:
        """Controls the optimum is found among (bang-bang plus straight)."""
        w = float(self.omega_max)
        return np.array([0.0]) if w == 0.0 else np.array([-w, 0.0, w])

    def flow(self, states, u, dt) -> np.ndarray:
        """Exact state after ``dt`` under constant control ``u`` (an arc or a line)."""
        s = np.asarray(states, dtype=float)
        x, y, th = s[..., 0], s[..., 1], s[..., 2]
        u = np.broadcast_to(np.asarray(u, dtype=float), th.shape)
        th1 = th + u * dt
        turning = np.abs(u * dt) > 1e-9
        safe_u = np.where(turning, u, 1.0)
        ax = np.where(turning, (np.sin(th1) - np.sin(th)) / safe_u, np.cos(th) * dt)
        ay = np.where(turning, (np.cos(th) - np.cos(th1)) / safe_u, np.sin(th) * dt)
        return np.stack([x + self.speed * ax, y + self.speed * ay, wrap_angle(th1)], axis=-1)
