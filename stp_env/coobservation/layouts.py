"""Section III-F on the paper's own inputs and on a family of generated layouts.

The surveillance-flow experiment (:func:`stp_env.coobservation.paper.survey_flows`) was first run on one layout of
this project's (:class:`~stp_env.coobservation.paper.SurveyTask`: boustrophedon routes and two thin forbidden
walls), where it needs K* = 4 surveillance robots with the ellipses and 5 with the exact regions. This module runs
it where the paper's text puts it and where one layout cannot speak for many:

* :func:`section2_survey`: Section II's map and zones with the routes Section II plans *without* the reachability
  constraints (the unsecured plan of its Fig. 2a, the routes Section III sets out to secure: "the robots' paths are
  planned without considering security", then secured by surveillance), zone 1 an obstacle the robots fly around,
  zones 2 and 3 forbidden;
* :func:`random_survey`: a layout drawn from a seed: three boustrophedon routes of two passes each at random heights,
  ends, directions and speeds, and two or three forbidden walls of random length and position between passes;
  draws whose routes pass too close to a wall to be secured at all (Algorithm 1 refuses two consecutive waypoints)
  are drawn again from the next sub-seed, and the number of such redraws is reported.

What the generator draws is the project's own choice (the paper shows one layout and gives no distribution).
``examples/coobservation_layouts.py`` runs both with the ellipses and with the exact regions and writes
``docs/coobservation_layouts.json`` and its figure.
"""

from __future__ import annotations

import numpy as np

from stp_env.coobservation import paper

WALL = 0.2
"""Thickness [m] of a generated forbidden wall (the published layout's walls are 0.2 m thick)."""


def section2_survey(plan, radius: float = 0.2) -> paper.SurveyTask:
    """Section III-F's problem on Section II's map: the routes ``plan`` (``(3, T + 1, 2)``, one waypoint per step,
    e.g. ``paper.plan(MapExplorationTask(), secured=False).q``), zones 2 and 3 forbidden, zone 1 an obstacle for the
    surveillance robots' transfers, the robots' ``v_max`` and Section III-F's checkpoint radius and weights."""
    task = paper.MapExplorationTask()
    plan = np.asarray(plan, float)
    if plan.ndim != 3 or plan.shape[0] != task.n_agents or plan.shape[2] != 2:
        raise ValueError(f"plan must be ({task.n_agents}, T + 1, 2); got shape {plan.shape}.")
    return paper.SurveyTask(lo=task.lo, hi=task.hi, v_max=task.v_max, radius=radius, forbidden=task.forbidden,
                            obstacles=task.obstacles, given_routes=tuple(_points(r) for r in plan))


def _points(route) -> tuple:
    return tuple(tuple(float(v) for v in p) for p in route)


def _draw(rng: np.random.Generator) -> paper.SurveyTask:
    """One candidate layout (may be unsecurable; :func:`random_survey` checks)."""
    while True:
        heights = np.sort(rng.uniform(0.8, 9.2, 6))
        if np.min(np.diff(heights)) >= 0.9:
            break
    order = rng.permutation(3)
    passes = tuple((float(heights[order[p]]), float(heights[order[p] + 3])) for p in range(3))
    x_range = (float(rng.uniform(0.3, 1.5)), float(rng.uniform(8.5, 9.7)))
    gaps = np.stack([heights[:-1], heights[1:]], 1)
    walls = []
    for k in rng.choice(len(gaps), size=int(rng.integers(2, 4)), replace=False):
        lo_y, hi_y = gaps[k]
        y = float(rng.uniform(lo_y + 0.35, hi_y - 0.35 - WALL)) if hi_y - lo_y > 0.7 + WALL else \
            float((lo_y + hi_y - WALL) / 2)
        length = float(rng.uniform(2.0, 4.0))
        # clear of the passes' ends, where a route turns to its next pass across the gaps
        x0 = float(rng.uniform(x_range[0] + 0.6, x_range[1] - 0.6 - length))
        walls.append(paper._box(x0, x0 + length, y, y + WALL))
    return paper.SurveyTask(passes=passes, x_range=x_range, alternate=bool(rng.integers(2)),
                            speed=float(rng.uniform(0.3, 0.4)), forbidden=tuple(walls))


def random_survey(seed: int, secure=None, max_draws: int = 50) -> tuple[paper.SurveyTask, int]:
    """A generated layout from ``seed`` and the number of draws rejected before it: candidates whose routes cannot
    be secured by any checkpoint placement under ``secure`` (default: the ellipse test of the layout) are drawn
    again from the next sub-seed."""
    from stp_env.coobservation import checkpoints

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    for rejected in range(max_draws):
        task = _draw(rng)
        test = secure or checkpoints.ellipse_test(task.forbidden, task.v_max, task.radius)
        try:
            for route in task.routes():
                checkpoints.secure_checkpoints(route, test)
        except checkpoints.UnsecurableRouteError:
            continue
        return task, rejected
    raise RuntimeError(f"seed {seed}: no securable layout in {max_draws} draws.")
