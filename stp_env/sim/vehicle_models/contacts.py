"""Collision events from pymunk sensor shapes, an independent check of the core's signed-distance events.

The core decides collisions from distances (:func:`stp_env.sim.core._events`): two flying vehicles within ``R_c``,
a vehicle where the buildings' signed-distance table (bilinear in its grid) is ``<= 0``. :class:`SensorWorld`
decides the same from geometry in a pymunk Space: every building a static ``Poly`` (its exact polygon, convex
parts from pymunk's decomposition), every vehicle a dynamic body with two sensor circles, one of radius ``R_c / 2``
(two of them overlap exactly when the centres are within ``R_c``) and a point-sized one for the buildings; the
contacts are collected by collision callbacks over a zero-length step. The two agree except within the table's
interpolation error of a building's boundary (tests/test_pymunk_backend.py measures it).
"""

from __future__ import annotations

import numpy as np

from stp_env.sim.vehicle_models.rigid_body import require_pymunk

VEHICLE, PROBE, BUILDING = 1, 2, 3   # collision types
PROBE_RADIUS = 1e-3                  # [m] the point-sized sensor that tests "inside a building"


class SensorWorld:
    """A pymunk Space with a scenario's buildings; :meth:`contacts` places the vehicles and reads the sensors."""

    def __init__(self, buildings, collision_radius: float):
        pymunk = require_pymunk()
        from pymunk import autogeometry

        self._pymunk = pymunk
        self.collision_radius = float(collision_radius)
        self.space = pymunk.Space()
        for building in buildings:
            vertices = [tuple(map(float, v)) for v in getattr(building, "vertices", building)]
            if _signed_area(vertices) < 0:
                vertices = vertices[::-1]
            for part in autogeometry.convex_decomposition(vertices + vertices[:1], 1e-6):
                shape = pymunk.Poly(self.space.static_body, part)
                shape.collision_type = BUILDING
                self.space.add(shape)
        self._hits: set = set()
        self._bodies: list = []
        self.space.on_collision(VEHICLE, VEHICLE, begin=self._record)
        self.space.on_collision(PROBE, BUILDING, begin=self._record)

    def _record(self, arbiter, space, data):
        a, b = arbiter.shapes
        self._hits.add((a.collision_type, getattr(a, "vehicle", -1), b.collision_type, getattr(b, "vehicle", -1)))

    def _ensure(self, n: int) -> None:
        pymunk = self._pymunk
        while len(self._bodies) < n:
            body = pymunk.Body(1.0, 1.0)
            near = pymunk.Circle(body, 0.5 * self.collision_radius)
            probe = pymunk.Circle(body, PROBE_RADIUS)
            for shape, kind in ((near, VEHICLE), (probe, PROBE)):
                shape.sensor, shape.collision_type = True, kind
                shape.vehicle = len(self._bodies)
            self._bodies.append((body, near, probe))

    def contacts(self, positions, active=None) -> tuple[np.ndarray, np.ndarray]:
        """``(hit_vehicle (N,), hit_building (N,))`` for vehicles at ``positions`` ``(N, 2)`` [m]; only ``active``
        ones (default: all) are in the space."""
        positions = np.asarray(positions, np.float64)
        n = len(positions)
        active = np.ones(n, bool) if active is None else np.asarray(active, bool)
        self._ensure(n)
        for body, near, probe in self._bodies:
            if body.space is not None:
                self.space.remove(body, near, probe)
        for i in np.flatnonzero(active):
            body, near, probe = self._bodies[i]
            body.position, body.velocity = tuple(positions[i]), (0.0, 0.0)
            self.space.add(body, near, probe)
        self._hits = set()
        self.space.step(1e-9)
        hit_vehicle, hit_building = np.zeros(n, bool), np.zeros(n, bool)
        for ta, ia, tb, ib in self._hits:
            if ta == VEHICLE and tb == VEHICLE:
                hit_vehicle[[ia, ib]] = True
            else:
                hit_building[ia if ta == PROBE else ib] = True
        return hit_vehicle, hit_building


def _signed_area(vertices) -> float:
    v = np.asarray(vertices)
    return 0.5 * float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
