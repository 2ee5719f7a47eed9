"""Section III-F on Section II's inputs and on generated layouts (``stp_env/coobservation/layouts.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from stp_env.coobservation import checkpoints, layouts, paper


@pytest.mark.slow
def test_generated_layouts_are_reproducible_securable_and_keep_walls_off_the_routes():
    for seed in range(4):
        task, rejected = layouts.random_survey(seed)
        again, _ = layouts.random_survey(seed)
        assert task == again and rejected >= 0
        routes = task.routes()
        assert routes.shape[0] == 3 and len(task.forbidden) in (2, 3)
        test = checkpoints.ellipse_test(task.forbidden, task.v_max, task.radius)
        for route in routes:
            cps = checkpoints.secure_checkpoints(route, test)        # securable: no UnsecurableRouteError
            assert cps[0] == 0 and cps[-1] == len(route) - 1
        for wall in task.forbidden:                                  # no waypoint inside a wall
            (x0, y0), _, (x1, y1), _ = wall
            inside = (routes[..., 0] >= x0) & (routes[..., 0] <= x1) & (routes[..., 1] >= y0) & (routes[..., 1] <= y1)
            assert not inside.any()
    assert layouts.random_survey(0)[0] != layouts.random_survey(1)[0]


def test_section2_routes_become_a_survey_task_with_its_zones_and_obstacle():
    base = paper.MapExplorationTask()
    starts, goals = np.asarray(base.starts), np.asarray(base.goals)
    s = np.linspace(0.0, 1.0, base.horizon + 1)[None, :, None]
    plan = starts[:, None, :] + s * (goals - starts)[:, None, :]           # straight lines, 21 waypoints each
    task = layouts.section2_survey(plan)
    assert task.forbidden == base.forbidden and task.obstacles == base.obstacles and task.v_max == base.v_max
    np.testing.assert_allclose(task.routes(), plan)
    with pytest.raises(ValueError, match="plan must be"):
        layouts.section2_survey(plan[:2])
