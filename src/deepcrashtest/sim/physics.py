"""Post-impact rigid-body physics with Box2D (top-down, no gravity).

Vehicles that collide leave the kinematic model and become Box2D dynamic boxes (mass from the
vehicle category, uniform density). Contact between bodies exchanges momentum (Box2D's impulse
solver, restitution ``RESTITUTION``, body-to-body friction ``BODY_FRICTION``). Tyre friction is a
Box2D friction joint to the ground per vehicle: sliding force up to ``mu * m * g`` at the centre and
a yaw-resisting torque up to ``mu * m * g * r`` (``r`` = distance from the centre to a wheel),
i.e. locked wheels sliding to rest.

Delta-v (crash severity) of a vehicle in a collision is ``|sum of contact impulses| / m`` over the
first contact episode of the pair (from the first touch until the bodies separate), read from the
solver's impulses, so tyre friction during the contact does not blur it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from Box2D import b2ContactListener, b2World, b2WorldManifold
from Box2D._Box2D import b2Contact___GetWorldManifold_internal as _world_manifold

G = 9.81
MU_TYRE = 0.8  # locked wheels on dry asphalt
RESTITUTION = 0.15  # vehicle-to-vehicle, moderate impact speeds
BODY_FRICTION = 0.3  # sheet metal sliding on sheet metal
SUBSTEP_S = 0.005


@dataclass
class Episode:
    """The first contact episode of a pair of bodies."""

    begin_time: float
    point: tuple[float, float]
    relative_speed: float = float("nan")
    impulse: dict[Any, np.ndarray] = field(default_factory=dict)
    ended: bool = False


class _Listener(b2ContactListener):
    def __init__(self, world: PhysicsWorld) -> None:
        super().__init__()
        self.world = world
        self._wm = b2WorldManifold()  # filled by each PostSolve (one object, not one per call)

    @staticmethod
    def _keys(contact: Any) -> tuple[Any, Any]:
        return contact.fixtureA.body.userData, contact.fixtureB.body.userData

    def BeginContact(self, contact: Any) -> None:  # noqa: N802 (Box2D API)
        ka, kb = self._keys(contact)
        if ka is None or kb is None:
            return
        pair = pair_key(ka, kb)
        if pair not in self.world.episodes:
            wm = contact.worldManifold
            pts = [tuple(p) for p in wm.points[: contact.manifold.pointCount]]
            point = tuple(np.mean(pts, axis=0)) if pts else (float("nan"), float("nan"))
            va, vb = contact.fixtureA.body.linearVelocity, contact.fixtureB.body.linearVelocity
            rel = float(np.hypot(va[0] - vb[0], va[1] - vb[1]))
            self.world.episodes[pair] = Episode(
                self.world.time, (float(point[0]), float(point[1])), rel, {ka: np.zeros(2), kb: np.zeros(2)}
            )

    def EndContact(self, contact: Any) -> None:  # noqa: N802
        ka, kb = self._keys(contact)
        ep = self.world.episodes.get(pair_key(ka, kb))
        if ep is not None:
            ep.ended = True

    def PostSolve(self, contact: Any, impulse: Any) -> None:  # noqa: N802
        ka, kb = self._keys(contact)
        ep = self.world.episodes.get(pair_key(ka, kb))
        if ep is None or ep.ended:
            return
        wm = self._wm  # ``contact.worldManifold`` without building a new SWIG object per call
        contact._b2Contact__GetWorldManifold_internal(wm)
        nx, ny = wm.normal  # the tangent is (ny, -nx)
        count = contact.manifold.pointCount
        sn, st = sum(impulse.normalImpulses[:count]), sum(impulse.tangentImpulses[:count])
        px, py = nx * sn + ny * st, ny * sn + -nx * st  # plain floats: numpy's arithmetic without its overhead
        ia, ib = ep.impulse[ka], ep.impulse[kb]
        ia[0], ia[1] = ia[0] - px, ia[1] - py  # Box2D: body A receives -P, body B +P (normal from A to B)
        ib[0], ib[1] = ib[0] + px, ib[1] + py


def pair_key(a: Any, b: Any) -> tuple[Any, Any]:
    """The key of a pair of bodies in ``episodes`` (order-independent)."""
    return (a, b) if str(a) <= str(b) else (b, a)


class PhysicsWorld:
    """A Box2D world of vehicle bodies keyed by any hashable key (vehicle index, ...)."""

    def __init__(self, mu: float = MU_TYRE, restitution: float = RESTITUTION, substep: float = SUBSTEP_S) -> None:
        self.world = b2World(gravity=(0.0, 0.0), doSleep=True)
        self.ground = self.world.CreateStaticBody()
        self.listener: b2ContactListener = _Listener(self)
        self.world.contactListener = self.listener
        self.mu, self.restitution, self.substep = mu, restitution, substep
        self.bodies: dict[Any, Any] = {}
        self.mass: dict[Any, float] = {}
        self.episodes: dict[tuple[Any, Any], Episode] = {}
        self.time = 0.0

    def add(
        self,
        key: Any,
        pose: np.ndarray,
        velocity: np.ndarray,
        omega: float,
        length: float,
        width: float,
        mass: float,
    ) -> None:
        """Add a vehicle at ``pose`` (x, y, yaw) moving with ``velocity`` (m/s, world) and yaw rate ``omega``."""
        body = self.world.CreateDynamicBody(
            position=(float(pose[0]), float(pose[1])),
            angle=float(pose[2]),
            linearVelocity=(float(velocity[0]), float(velocity[1])),
            angularVelocity=float(omega),
            bullet=True,
            userData=key,
        )
        body.CreatePolygonFixture(
            box=(length / 2, width / 2),
            density=mass / (length * width),
            friction=BODY_FRICTION,
            restitution=self.restitution,
        )
        if self.mu > 0:
            r = float(np.hypot(0.3 * length, 0.4 * width))  # centre to a wheel
            self.world.CreateFrictionJoint(
                bodyA=self.ground,
                bodyB=body,
                localAnchorA=(float(pose[0]), float(pose[1])),
                localAnchorB=(0.0, 0.0),
                maxForce=self.mu * mass * G,
                maxTorque=self.mu * mass * G * r,
            )
        self.bodies[key] = body
        self.mass[key] = float(body.mass)

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds in sub-steps of at most ``substep``."""
        n = max(1, math.ceil(dt / self.substep - 1e-9))
        h = dt / n
        for _ in range(n):
            self.world.Step(h, 10, 4)
            self.time += h

    def state(self, key: Any) -> tuple[np.ndarray, np.ndarray, float]:
        """(x, y, yaw, speed), velocity (2,) and yaw rate of a body."""
        b = self.bodies[key]
        v = np.array(tuple(b.linearVelocity))
        return np.array([b.position[0], b.position[1], b.angle, float(np.hypot(*v))]), v, float(b.angularVelocity)

    def delta_v(self, a: Any, b: Any) -> dict[Any, float]:
        """Delta-v (m/s) of both bodies over their first contact episode (NaN when they never touched)."""
        ep = self.episodes.get(pair_key(a, b))
        if ep is None:
            return {a: float("nan"), b: float("nan")}
        return {k: float(np.hypot(*ep.impulse[k]) / self.mass[k]) for k in (a, b)}

    def episode_open(self, a: Any, b: Any) -> bool:
        ep = self.episodes.get(pair_key(a, b))
        return ep is None or not ep.ended


class _PairListener(b2ContactListener):
    """:class:`_Listener` for a world of two bodies keyed "a" and "b" (:func:`impact_delta_v`): every contact is
    between them, so which body is the contact's fixture A is read once, when it begins, instead of at every
    solver report (the Python side of a batch's delta-v); the same impulse sums, in the same order."""

    def __init__(self, world: PhysicsWorld) -> None:
        super().__init__()
        self.world = world
        self._wm = b2WorldManifold()
        self.episode: Episode | None = None
        self.ended = False
        self._sum = {"a": [0.0, 0.0], "b": [0.0, 0.0]}
        self._first, self._second = self._sum["a"], self._sum["b"]  # fixture A's and B's sums (set at the begin)

    def BeginContact(self, contact: Any) -> None:  # noqa: N802 (Box2D API)
        if self.episode is not None:
            return
        ka, kb = _Listener._keys(contact)
        wm = contact.worldManifold
        pts = [tuple(p) for p in wm.points[: contact.manifold.pointCount]]
        point = tuple(np.mean(pts, axis=0)) if pts else (float("nan"), float("nan"))
        va, vb = contact.fixtureA.body.linearVelocity, contact.fixtureB.body.linearVelocity
        rel = float(np.hypot(va[0] - vb[0], va[1] - vb[1]))
        self.episode = Episode(self.world.time, (float(point[0]), float(point[1])), rel)
        self._first, self._second = self._sum[ka], self._sum[kb]

    def EndContact(self, contact: Any) -> None:  # noqa: N802
        if self.episode is not None:
            self.ended = True

    def PreSolve(self, contact: Any, old_manifold: Any) -> None:  # noqa: N802
        """Nothing, as Box2D's own: defined here so that each contact's report does not call back into the C++
        base class (~10 % of an impact's CPU)."""

    def PostSolve(self, contact: Any, impulse: Any) -> None:  # noqa: N802
        if self.episode is None or self.ended:
            return
        wm = self._wm
        _world_manifold(contact, wm)
        normal = wm.normal
        nx, ny = normal.x, normal.y
        # the sums of the solved points' impulses (the contact manifold's ``pointCount`` of them), as ``sum()`` adds
        ni, ti = impulse.normalImpulses, impulse.tangentImpulses
        if impulse.count == 2:
            sn, st = ni[0] + ni[1], ti[0] + ti[1]
        else:
            sn, st = sum(ni[: impulse.count]), sum(ti[: impulse.count])
        px, py = nx * sn + ny * st, ny * sn + -nx * st
        ia, ib = self._first, self._second  # fixture A's body receives -P, B's +P
        ia[0], ia[1] = ia[0] - px, ia[1] - py
        ib[0], ib[1] = ib[0] + px, ib[1] + py

    def delta_v(self, key: str) -> float:
        """Delta-v (m/s) of body ``key`` over the episode (NaN when the bodies never touched)."""
        if self.episode is None:
            return float("nan")
        return float(np.hypot(*np.array(self._sum[key])) / self.world.mass[key])


def impact_delta_v(
    pose_a: np.ndarray,
    vel_a: np.ndarray,
    omega_a: float,
    size_a: tuple[float, float, float],
    pose_b: np.ndarray,
    vel_b: np.ndarray,
    omega_b: float,
    size_b: tuple[float, float, float],
    max_time: float = 1.0,
    mu: float = MU_TYRE,
) -> tuple[float, float, tuple[float, float]]:
    """Simulate one two-vehicle impact from just before contact until the bodies separate.

    ``size_*`` = (length, width, mass). Returns (delta-v of A, delta-v of B, impact point).
    """
    w = PhysicsWorld(mu=mu)
    listener = w.listener = _PairListener(w)
    w.world.contactListener = listener
    w.add("a", pose_a, vel_a, omega_a, *size_a)
    w.add("b", pose_b, vel_b, omega_b, *size_b)
    world_step, t = w.world.Step, w.time
    while t < max_time:  # ``w.step(SUBSTEP_S)``: one sub-step each
        world_step(SUBSTEP_S, 10, 4)
        t += SUBSTEP_S
        w.time = t
        if listener.ended:
            break
    ep = listener.episode
    return listener.delta_v("a"), listener.delta_v("b"), ep.point if ep is not None else (float("nan"), float("nan"))
