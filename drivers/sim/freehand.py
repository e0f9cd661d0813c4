"""The freehand protocol: a hand-guided traction trial whose force is no function of time.

The paper's protocol pulls at one speed until one force (``k·v`` is 0.4 N/s in all its
conditions), so the force can be read from the time since the pull began. Here the simulated
operator pulls towards random force levels at a speed that changes every fraction of a second,
pauses mid-pull, releases part of the force and pulls again, and at each level either holds
the force (the grasper creeps) or holds the grasper still (the force relaxes). The tissue is the
standard linear solid of :mod:`vbfe.drivers.sim.mechanics`; every step has a closed-form
solution, so the trial is a short list of steps (JSON-able) replayed exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from vbfe.drivers.sim.mechanics import HOLD, PULL, REST

RELEASE = 4  # phase: the grasper gives way (a partial release)
MOVE, STILL, FORCE_HOLD = 0, 1, 2  # step kinds: constant grasper speed, grasper still, force held


@dataclass(frozen=True)
class FreehandProtocol:
    """Rest for ``rest_s``, then ``steps`` of ``(kind, speed m/s, seconds)``; after the last
    step the grasper stays still. ``target_force_n`` is the highest force level."""

    stiffness_n_per_m: float
    steps: tuple[tuple[int, float, float], ...]
    rest_s: float = 0.5
    session_s: float = 15.0
    target_force_n: float = 3.0
    relaxation_ratio: float = 0.5  # k1 / k, as in TractionProtocol
    relaxation_time_s: float = 1.5

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        stiffness_n_per_m: float,
        session_s: float,
        target_force_n: float = 3.0,
        rest_s: float = 0.5,
        force_rate_n_per_s: tuple[float, float] = (0.15, 1.5),
    ) -> FreehandProtocol:
        """A random trial: force levels uniform in ``[0.15, 1] × target_force_n`` (at least
        0.3 N from the force before), reached at force rates (``k·v``) log-uniform in
        ``force_rate_n_per_s`` that change every 0.2–1 s, with pauses, force holds and still
        holds of 0.3–2 s at the levels."""
        protocol = cls(stiffness_n_per_m, (), rest_s, session_s, target_force_n)
        k, steps = stiffness_n_per_m, []
        u = q = 0.0
        t = rest_s
        lo, hi = np.log(force_rate_n_per_s)
        while t < session_s:
            force = float(protocol._force(u, q))
            level = force
            while abs(level - force) < 0.3:
                level = float(rng.uniform(0.15, 1.0)) * target_force_n
            direction = 1.0 if level > force else -1.0
            while t < session_s and direction * (level - protocol._force(u, q)) > 0:
                if rng.random() < 0.15:  # the hand stops for a moment
                    steps.append((STILL, 0.0, float(rng.uniform(0.2, 0.8))))
                else:
                    speed = direction * float(np.exp(rng.uniform(lo, hi))) / k
                    chunk = float(rng.uniform(0.2, 1.0))
                    steps.append((MOVE, speed, protocol._reach(u, q, speed, chunk, level)))
                u, q = protocol._after(u, q, steps[-1])
                t += steps[-1][2]
            kind = FORCE_HOLD if rng.random() < 0.6 else STILL
            steps.append((kind, 0.0, float(rng.uniform(0.3, 2.0))))
            u, q = protocol._after(u, q, steps[-1])
            t += steps[-1][2]
        return cls(stiffness_n_per_m, tuple(steps), rest_s, session_s, target_force_n)

    @property
    def _k1(self) -> float:
        return self.relaxation_ratio * self.stiffness_n_per_m

    def _force(self, u: float | np.ndarray, q: float | np.ndarray) -> float | np.ndarray:
        return self.stiffness_n_per_m * u + self._k1 * (u - q)

    def _evolve(
        self, u0: np.ndarray, q0: np.ndarray, kind: np.ndarray, speed: np.ndarray, dt: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Grasper displacement and Maxwell-arm state ``dt`` into a step from ``(u0, q0)``."""
        k, k1, tau = self.stiffness_n_per_m, self._k1, self.relaxation_time_s
        # moving at speed v (v = 0: still): q follows u with lag v·τ
        u_move = u0 + speed * dt
        q_move = u_move - speed * tau + (q0 - u0 + speed * tau) * np.exp(-dt / tau)
        # force held at F0: q relaxes to F0/k with time constant τ (k + k1) / k
        f0 = self._force(u0, q0)
        q_hold = f0 / k + (q0 - f0 / k) * np.exp(-dt * k / (tau * (k + k1)))
        u_hold = (f0 + k1 * q_hold) / (k + k1)
        holding = kind == FORCE_HOLD
        return np.where(holding, u_hold, u_move), np.where(holding, q_hold, q_move)

    def _after(self, u: float, q: float, step: tuple[int, float, float]) -> tuple[float, float]:
        kind, speed, seconds = step
        un, qn = self._evolve(
            np.array(u), np.array(q), np.array(kind), np.array(speed), np.array(seconds)
        )
        return float(un), float(qn)

    def _reach(self, u: float, q: float, speed: float, seconds: float, level: float) -> float:
        """How long to move at ``speed`` (at most ``seconds``) until the force reaches ``level``."""
        times = np.linspace(0.0, seconds, 201)
        un, qn = self._evolve(
            np.full(201, u), np.full(201, q), np.full(201, MOVE), np.full(201, speed), times
        )
        past = np.flatnonzero(np.sign(speed) * (self._force(un, qn) - level) >= 0)
        if not len(past):
            return seconds
        lo, hi = times[max(past[0] - 1, 0)], times[past[0]]
        for _ in range(30):
            mid = (lo + hi) / 2
            um, qm = self._after(u, q, (MOVE, speed, mid))
            lo, hi = (lo, mid) if np.sign(speed) * (self._force(um, qm) - level) >= 0 else (mid, hi)
        return hi

    @cached_property
    def _starts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per step: start time, kind, speed, and the state (u, q) at its start; a final
        "still" step runs forever."""
        steps = [*self.steps, (STILL, 0.0, math.inf)]
        kind = np.array([s[0] for s in steps])
        speed = np.array([s[1] for s in steps])
        start = self.rest_s + np.concatenate([[0.0], np.cumsum([s[2] for s in self.steps])])
        u, q = np.zeros(len(steps)), np.zeros(len(steps))
        for i, step in enumerate(self.steps):
            u[i + 1], q[i + 1] = self._after(u[i], q[i], step)
        return start, kind, speed, u, q

    def duration_s(self) -> float:
        """Length of the trial (rest and steps)."""
        return self.rest_s + sum(s[2] for s in self.steps)

    def max_displacement_m(self) -> float:
        """The largest grasper displacement (reached at the end of a step)."""
        return float(self._starts[3].max())

    def state(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grasper displacement (m), force (N) and phase (REST, PULL, RELEASE or HOLD — a
        force hold or a still grasper) at trial times ``t_s``."""
        t = np.asarray(t_s, np.float64)
        start, kind, speed, u0, q0 = self._starts
        i = np.clip(np.searchsorted(start, t, side="right") - 1, 0, len(start) - 1)
        u, q = self._evolve(u0[i], q0[i], kind[i], speed[i], np.maximum(t - start[i], 0.0))
        resting = t < self.rest_s
        u, q = np.where(resting, 0.0, u), np.where(resting, 0.0, q)
        moving = (kind[i] == MOVE) & ~resting
        phase = np.where(
            resting, REST, np.where(~moving, HOLD, np.where(speed[i] > 0, PULL, RELEASE))
        )
        return u, np.asarray(self._force(u, q)), phase
