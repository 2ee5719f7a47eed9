"""What the assembly checks of its inputs before it builds anything (host side, numpy): the checks of
:func:`stp_env.assembly.make_params` (:func:`check_inputs`: the reachability tables are the scenario's, the
simulator's settings lie inside what the proofs certify, the plan is a flight of the planning dynamics) and the plan
checks :func:`stp_env.assembly.with_plan` shares with it (:func:`plan_faults`, :func:`plan_period`). Every refusal
is a ``ValueError`` of one line; what ``allow_uncertified`` lets through is a ``UserWarning``.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from stp_env.reach.fall_rate import FALL_RATE_BAND
from stp_env.sim.config import EnvConfig
from stp_env.sim.margins import default_avoid_margin

PERIOD_DECIMALS = 6
"""Sample periods are compared to the microsecond: sample times are sums of float32 and float64 offsets (a replanned
vehicle's times differ from ``k * dt`` in the ninth digit)."""


def sample_period(times) -> float:
    """The sample period of one trajectory's ``times`` [s], rounded to :data:`PERIOD_DECIMALS`."""
    return round(float(times[1] - times[0]), PERIOD_DECIMALS)


def plan_period(plan) -> float:
    """The one sample period of ``plan``'s trajectories [s] (1 s when none has two samples); ``ValueError`` if they
    use several."""
    steps = {sample_period(v.plan.times) for v in plan.vehicles if len(v.plan.times) > 1}
    if len(steps) > 1:
        raise ValueError(f"The plan's vehicles use different sample periods {sorted(steps)}; the simulator needs one.")
    return steps.pop() if steps else 1.0


def plan_faults(plan, *, dt: float, planning_v, planning_omega_max: float, targets=None, target_radii=None,
                scenario=None) -> dict[int, list[str]]:
    """What keeps each vehicle's trajectory in ``plan`` from being a flight of the planning dynamics (``{index:
    [reasons]}``, empty when none): with ``scenario``, every check of
    :func:`stp_env.planning.verify.trajectory_faults` (its start, its arrival, its priority); without it the
    dynamics-only checks of :func:`stp_env.planning.verify.flight_faults` (finite samples ``dt`` apart, controls in
    ``U^p``, exact steps), each flight up to its first sample in its target (``targets``, ``target_radii``)
    shrunk by the plan's tracking bound: for a plan made in the air (replanning), whose starts are not the
    scenario's."""
    from stp_env.planning import verify

    if scenario is not None:
        return verify.trajectory_faults(plan, scenario)
    faults = {}
    for i, veh in enumerate(plan.vehicles):
        p = veh.plan
        end = None
        if targets is not None:
            states = np.asarray(p.states, np.float64)
            if states.ndim == 2 and states.shape[1:] == (3,) and len(states) and np.all(np.isfinite(states)):
                end = verify.flight_end(states, np.asarray(targets[i], np.float64), float(target_radii[i]),
                                        float(plan.tracking_bound))
        why = verify.flight_faults(p.times, p.states, p.controls, p.t_ldt, dt=dt, planning_v=planning_v,
                                   planning_omega_max=planning_omega_max, end=end)
        if why:
            faults[veh.index] = why
    return faults


def faults_message(faults: dict[int, list[str]], what: str) -> str:
    """The refusal of a plan with ``faults`` (:func:`plan_faults`), ``what`` naming the plan."""
    first = min(faults)
    more = f" (and {len(faults) - 1} more vehicles)" if len(faults) > 1 else ""
    return (f"{what} is not a flight of the planning dynamics U^p, which the tracking-error bound assumes of every "
            f"reference: vehicle {first}: {'; '.join(faults[first])}{more}. Pass allow_uncertified=True to simulate "
            "it anyway, those vehicles' violations counting as assumption failures.")


def table_mismatch(scenario, avoid, tracking) -> list[str]:
    """Where the avoid region ``avoid`` and the tracking bound ``tracking`` were computed for another vehicle,
    planning set, ``R_c`` or ``t_IAT`` than ``scenario``'s, one line each (empty when they are its own)."""
    acfg, tcfg = avoid.config, tracking.config
    return [f"{name}: scenario {a!r}, {what} {b!r}" for what, name, a, b in (
        ("avoid region", "collision_radius", scenario.collision_radius, acfg.collision_radius),
        ("avoid region", "t_iat", scenario.t_iat, acfg.t_iat),
        *[(f"{what}", f"{who} {field}", getattr(scenario.vehicle, field), getattr(model, field))
          for what, who, model in (("avoid region", "vehicle", acfg.vehicle), ("avoid region", "intruder",
                                                                                 acfg.intruder),
                                   ("tracking bound", "vehicle", tcfg.vehicle))
          for field in ("v_min", "v_max", "omega_max", "wind", "heading_disturbance")],
        ("tracking bound", "planning v_min", scenario.planning_v[0], tcfg.planning_v[0]),
        ("tracking bound", "planning v_max", scenario.planning_v[1], tcfg.planning_v[1]),
        ("tracking bound", "planning omega_max", scenario.planning_omega_max, tcfg.planning_omega_max),
    ) if not math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9)]


def _avoid_margin(avoid, config: EnvConfig) -> tuple[float, list[str]]:
    """The avoid margin [m] (``config.avoid_margin``, else the certified one of
    :func:`stp_env.sim.margins.default_avoid_margin`) and what of it lies outside the proofs; ``ValueError`` when one
    inner step of the value's fastest fall leaves the band in which that rate was bounded."""
    uncertified = []
    if math.isfinite(avoid.table_error):
        certified_margin = default_avoid_margin(config.control_dt, avoid.fall_rate, avoid.table_error)
    else:  # a table without a closed-loop certificate: the sampling part of the margin, and no certified one
        uncertified.append("the avoid region is not certified in closed loop")
        certified_margin = default_avoid_margin(config.control_dt, avoid.fall_rate)
    margin = certified_margin if config.avoid_margin is None else config.avoid_margin
    step_fall = config.control_dt * avoid.fall_rate
    if step_fall > FALL_RATE_BAND:
        raise ValueError(f"One inner step ({config.control_dt} s) of the avoid value's fastest fall is "
                         f"{step_fall:.1f} m, beyond the {FALL_RATE_BAND} m band in which that rate was bounded; use a "
                         "smaller control_dt.")
    if margin < certified_margin - 1e-6 and math.isfinite(avoid.table_error):
        uncertified.append(f"avoid_margin {margin:.3f} m, below the certified {certified_margin:.3f} m (one inner step "
                           f"of the value's fastest fall, {step_fall:.3f} m, plus the table's closed-loop error "
                           f"{avoid.table_error:.3f} m and rounding)")
    return margin, uncertified


class CheckedInputs(NamedTuple):
    """What :func:`check_inputs` found, which the builders of :func:`stp_env.assembly.make_params` read."""

    faults: dict[int, list[str]]  # the vehicles whose trajectories are not flights of U^p (plan_faults)
    uncertified: list[str]        # the settings outside the proofs, which make every vehicle uncertified
    detection_range: float        # d^A [m] (eq. 16)
    d_sense: float                # [m] the sensing range, >= d^A
    avoid_margin: float           # [m] avoid start when V^A <= this margin


def check_inputs(scenario, plan, avoid, tracking, config: EnvConfig) -> CheckedInputs:
    """Every check of :func:`stp_env.assembly.make_params` (see there), in its order, before anything is built:
    ``ValueError`` for what is refused, a ``UserWarning`` (attributed to ``make_params``' caller) for what
    ``config.allow_uncertified`` lets through."""
    n = scenario.n_vehicles
    if len(plan.vehicles) != n:
        raise ValueError(f"The plan has {len(plan.vehicles)} vehicles but scenario {scenario.name!r} has {n}.")
    mismatch = table_mismatch(scenario, avoid, tracking)
    if mismatch:
        raise ValueError("The reachability tables were computed for another scenario: " + "; ".join(mismatch) + ".")
    uncertified = []  # settings of the simulator outside the proofs, accepted with allow_uncertified
    if not config.control_dt_certified:
        uncertified.append(f"control_dt {config.control_dt} s")
    if not tracking.certified:
        uncertified.append(f"the tracking-error bound {tracking.bound:.3f} m is not certified in closed loop")
    faults = plan_faults(plan, dt=float(scenario.time_step), planning_v=scenario.planning_v,
                         planning_omega_max=scenario.planning_omega_max, scenario=scenario)
    if faults and not config.allow_uncertified:
        raise ValueError(faults_message(faults, f"the plan of scenario {scenario.name!r}"))
    if faults:
        first = min(faults)
        warnings.warn(f"{len(faults)} vehicle(s) of scenario {scenario.name!r} fly trajectories that are not "
                      f"flights of U^p (vehicle {first}: {'; '.join(faults[first])}): their violations count as "
                      "assumption failures.", stacklevel=3)
    plan_period(plan)
    d_a = float(avoid.detection_range())
    d_sense = 1.5 * d_a if config.d_sense is None else config.d_sense
    if d_sense < d_a:
        raise ValueError(f"d_sense ({d_sense} m) must be at least the detection range d^A = {d_a:.1f} m (eq. 16): "
                         "a vehicle must see the intruder before it has to avoid it.")
    margin, margin_uncertified = _avoid_margin(avoid, config)
    uncertified += margin_uncertified
    if config.dt > float(scenario.t_iat) * (1 + 1e-6):
        # the intruder leaves at the first decision step at least t_IAT after it appeared: one step of dt > t_IAT
        # keeps it dt seconds, longer than Assumption 1's t_IAT, for which the avoid tables and k̄ are computed
        uncertified.append(f"dt {config.dt:g} s is longer than t_IAT {float(scenario.t_iat):g} s (the intruder "
                           "would stay a whole step, past Assumption 1's t_IAT)")
    if uncertified and not config.allow_uncertified:
        raise ValueError("Outside what the guarantees certify: " + "; ".join(uncertified) + ". Pass "
                         "allow_uncertified=True to simulate it anyway (violations then count as assumption "
                         "failures).")
    if uncertified:
        warnings.warn("Simulating outside what the guarantees certify (" + "; ".join(uncertified) + "): every "
                      "vehicle's violations count as assumption failures.", stacklevel=3)
    return CheckedInputs(faults=faults, uncertified=uncertified, detection_range=d_a, d_sense=d_sense,
                         avoid_margin=margin)
