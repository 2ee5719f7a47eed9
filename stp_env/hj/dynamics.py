"""Control- and disturbance-affine dynamics for the level-set solver.

    dx/dt = f(x) + G_u(x) u + G_d(x) d,   u in U (control set),  d in D (disturbance set).

States, inputs and co-states are passed *structure-of-arrays*: a tuple with one array per component. A single
state is a tuple of scalars; a whole grid is :meth:`Grid.broadcast_states`, a tuple of broadcastable arrays.
The same code therefore evaluates one state inside a controller and a million grid nodes inside the solver,
and zero Jacobian entries (written as the Python float ``0.0``) cost nothing.

Hamiltonian and player roles
----------------------------
Every problem in this package solves ``D_t V + H(x, D_x V) = 0`` with

    H(x, p) = opt_u opt_d  p . f(x, u, d),

where ``opt_u`` is ``min`` or ``max`` according to ``control_mode``, and likewise for the disturbance. Because
``p . f`` is separable in ``u`` and ``d``, the order of the two optimisations does not matter and both are in
closed form (:mod:`stp_env.hj.sets`). The role to choose follows the reachability literature (intruder paper,
Section III-A): a player that tries to *reach* a target in a backward problem minimises (``"min"``), a player that
tries to *avoid* it maximises (``"max"``); in a forward reachable set, a player whose every input is to be
covered maximises.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable, Sequence

import jax.numpy as jnp

from stp_env.hj.sets import ProductSet

_MODES = ("min", "max")


def _is_zero(x) -> bool:
    return isinstance(x, (int, float)) and x == 0


def _dot(p: Sequence, column: Sequence):
    """``sum_i p_i column_i`` skipping literal zeros."""
    terms = [pi * ci for pi, ci in zip(p, column) if not _is_zero(ci)]
    return sum(terms[1:], terms[0]) if terms else 0.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class ControlAffineDynamics(abc.ABC):
    """Base class. Subclasses are frozen dataclasses (hashable: they are static jit arguments) and implement
    :meth:`open_loop`, :meth:`control_jacobian`, :meth:`disturbance_jacobian` and :attr:`state_dim`.

    Attributes:
        control_mode: ``"min"`` or ``"max"``: how the control optimises ``p . f``.
        disturbance_mode: ``"min"`` or ``"max"``: how the disturbance optimises ``p . f``.
    """

    control_mode: str = "min"
    disturbance_mode: str = "max"

    def __post_init__(self) -> None:
        for name in ("control_mode", "disturbance_mode"):
            mode = getattr(self, name)
            if mode not in _MODES:
                raise ValueError(f"{name} must be 'min' or 'max'; got {mode!r}.")

    # ----------------------------------------------------------- to implement
    @property
    @abc.abstractmethod
    def state_dim(self) -> int: ...

    @property
    @abc.abstractmethod
    def control_space(self) -> ProductSet: ...

    @property
    @abc.abstractmethod
    def disturbance_space(self) -> ProductSet: ...

    @abc.abstractmethod
    def open_loop(self, x: Sequence) -> tuple:
        """``f(x)``: ``state_dim`` entries. Dynamics are time-invariant (time enters problems through
        targets and obstacles), so the solver computes dissipation and the CFL step once."""

    @abc.abstractmethod
    def control_jacobian(self, x: Sequence) -> tuple:
        """``G_u(x)``: ``state_dim`` rows of ``control_space.dim`` entries."""

    @abc.abstractmethod
    def disturbance_jacobian(self, x: Sequence) -> tuple:
        """``G_d(x)``: ``state_dim`` rows of ``disturbance_space.dim`` entries."""

    # ------------------------------------------------------------ derived
    def with_modes(self, control_mode: str | None = None, disturbance_mode: str | None = None):
        """A copy with other player roles."""
        return dataclasses.replace(
            self,
            control_mode=self.control_mode if control_mode is None else control_mode,
            disturbance_mode=self.disturbance_mode if disturbance_mode is None else disturbance_mode,
        )

    def __call__(self, x: Sequence, u: Sequence, d: Sequence | None = None) -> tuple:
        """``dx/dt`` for given control ``u`` and disturbance ``d`` (zero disturbance if ``None``)."""
        f0 = self.open_loop(x)
        gu = self.control_jacobian(x)
        out = [f0[i] + _dot(u, gu[i]) for i in range(self.state_dim)]
        if d is not None and self.disturbance_space.dim:
            gd = self.disturbance_jacobian(x)
            out = [out[i] + _dot(d, gd[i]) for i in range(self.state_dim)]
        return tuple(out)

    def _input_directions(self, x, p):
        gu = self.control_jacobian(x)
        qu = tuple(_dot(p, [gu[i][j] for i in range(self.state_dim)]) for j in range(self.control_space.dim))
        qd: tuple = ()
        if self.disturbance_space.dim:
            gd = self.disturbance_jacobian(x)
            qd = tuple(_dot(p, [gd[i][j] for i in range(self.state_dim)])
                       for j in range(self.disturbance_space.dim))
        return qu, qd

    def hamiltonian(self, x: Sequence, p: Sequence):
        """``H(x, p) = p . f(x) + opt_u (p . G_u u) + opt_d (p . G_d d)`` in closed form."""
        qu, qd = self._input_directions(x, p)
        h = _dot(p, self.open_loop(x))
        h = h + self.control_space.optimum(qu, self.control_mode)
        if qd:
            h = h + self.disturbance_space.optimum(qd, self.disturbance_mode)
        return h

    def hamiltonian_at(self, t, x: Sequence, p: Sequence, params=None):
        """``H(t, x, p)`` as the solver calls it, with the time ``t`` of the stage and the ``dynamics_params``
        pytree of :func:`stp_env.hj.solve`. Time-invariant dynamics ignore both (:meth:`hamiltonian`);
        time-varying ones (:class:`FeedbackDynamics`) override this."""
        del t, params
        return self.hamiltonian(x, p)

    def partial_bounds_at(self, t, x: Sequence, params=None) -> tuple:
        """Local dissipation coefficients as the solver asks for them (stage time ``t``, ``dynamics_params``):
        :meth:`partial_bounds` for time-invariant dynamics."""
        del t, params
        return self.partial_bounds(x)

    def optimal_control(self, x: Sequence, p: Sequence) -> tuple:
        """``arg opt_u p . G_u(x) u`` (the control realising :meth:`hamiltonian`)."""
        qu, _ = self._input_directions(x, p)
        return self.control_space.extreme(qu, self.control_mode)

    def optimal_disturbance(self, x: Sequence, p: Sequence) -> tuple:
        """``arg opt_d p . G_d(x) d`` (the disturbance realising :meth:`hamiltonian`)."""
        _, qd = self._input_directions(x, p)
        if not qd:
            return ()
        return self.disturbance_space.extreme(qd, self.disturbance_mode)

    def partial_bounds(self, x: Sequence) -> tuple:
        """``alpha_i(x) >= max_{u, d} |f_i(x, u, d)| = |dH/dp_i|`` bound used for Lax-Friedrichs dissipation
        and for the CFL condition.

        Tight for products of boxes and balls: ``|f_i(x, c_u, c_d)| + sum_blocks max |G_i,block e|`` where
        ``c`` are the set centres and ``e`` ranges over the centred block.
        """
        return _rate_bounds(self, x, self.control_space.center(), self.control_space.blocks)


def _rate_bounds(dyn: ControlAffineDynamics, x: Sequence, u, control_blocks) -> tuple:
    """``|f_i(x) + G_u,i(x) u + G_d,i(x) c_d|`` plus ``max |G_i,block e|`` over each block of ``control_blocks``
    (the control's spread about ``u``; none for a feedback law) and of the disturbance set, per state ``i``."""
    f0 = dyn.open_loop(x)
    gu = dyn.control_jacobian(x)
    gd = dyn.disturbance_jacobian(x) if dyn.disturbance_space.dim else None
    cd = dyn.disturbance_space.center()
    out = []
    for i in range(dyn.state_dim):
        centre = f0[i] + _dot(u, gu[i])
        if gd is not None:
            centre = centre + _dot(cd, gd[i])
        a = jnp.abs(centre) if not _is_zero(centre) else 0.0
        k = 0
        for b in control_blocks:
            a = a + b.max_abs_linear(gu[i][k:k + b.dim])
            k += b.dim
        if gd is not None:
            k = 0
            for b in dyn.disturbance_space.blocks:
                a = a + b.max_abs_linear(gd[i][k:k + b.dim])
                k += b.dim
        out.append(a)
    return tuple(out)


@dataclasses.dataclass(frozen=True, kw_only=True)
class FeedbackDynamics(ControlAffineDynamics):
    """Closed-loop dynamics of a control-affine system under a given state-feedback law (SPP paper eq. 14):

        dx/dt = f(x) + G_u(x) kappa(t, x; params) + G_d(x) d,   d in D,

    so that the control no longer appears as an input and only the disturbance plays (eq. 17):
    ``H(t, x, p) = p . (f(x) + G_u(x) kappa(t, x)) + opt_d p . G_d(x) d``.

    Attributes:
        base: the open-loop dynamics (its ``control_space`` bounds the feedback, its disturbance set and the
            ``disturbance_mode`` of this object are used).
        feedback: jittable ``kappa(t, x, params) -> tuple`` of ``base.control_space.dim`` arrays broadcastable
            against ``x`` (structure-of-arrays, as everywhere in this module). The solver evaluates it on the whole
            grid at the time of every Runge-Kutta stage, with ``params`` the ``dynamics_params`` pytree given to
            :func:`stp_env.hj.solve` (traced: tables such as a value function over time slices change without
            recompiling). It must be hashable (a module-level function or a frozen dataclass), since the
            dynamics are a static argument of the compiled solver loop; and its values must lie in
            ``base.control_space``: the dissipation coefficients and the CFL step are the base's bounds over all
            controls and disturbances (:meth:`partial_bounds`), valid for any feedback inside ``U`` and
            time-invariant, so the step is still computed once.
    """

    base: ControlAffineDynamics
    feedback: Callable

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.base, ControlAffineDynamics):
            raise TypeError(f"base must be a ControlAffineDynamics; got {type(self.base).__name__}.")
        if isinstance(self.base, FeedbackDynamics):
            raise TypeError("base is already closed-loop; give the open-loop dynamics.")
        if not callable(self.feedback):
            raise TypeError(f"feedback must be callable (t, x, params) -> control; got {self.feedback!r}.")
        try:
            hash(self.feedback)
        except TypeError:
            raise TypeError("feedback must be hashable (a module-level function or a frozen dataclass): the "
                            "dynamics are a static argument of the compiled solver loop.") from None

    @property
    def state_dim(self) -> int:
        return self.base.state_dim

    @property
    def control_space(self) -> ProductSet:
        return self.base.control_space

    @property
    def disturbance_space(self) -> ProductSet:
        return self.base.disturbance_space

    def open_loop(self, x):
        return self.base.open_loop(x)

    def control_jacobian(self, x):
        return self.base.control_jacobian(x)

    def disturbance_jacobian(self, x):
        return self.base.disturbance_jacobian(x)

    def closed_loop(self, t, x: Sequence, params=None, d: Sequence | None = None) -> tuple:
        """``dx/dt`` under the feedback at time ``t`` and disturbance ``d`` (zero if ``None``)."""
        return self.__call__(x, self.feedback(t, x, params), d)

    def hamiltonian(self, x: Sequence, p: Sequence):
        raise TypeError("FeedbackDynamics are time-varying: use hamiltonian_at(t, x, p, params) (as solve() does).")

    def hamiltonian_at(self, t, x: Sequence, p: Sequence, params=None):
        """``p . (f(x) + G_u(x) kappa(t, x)) + opt_d p . G_d(x) d`` (SPP paper eq. 17 in this package's sign
        convention: forward problems that cover every disturbance use ``disturbance_mode="max"``)."""
        u = self.feedback(t, x, params)
        if len(u) != self.control_space.dim:
            raise ValueError(f"feedback returned {len(u)} control components; the control space has "
                             f"{self.control_space.dim}.")
        qu, qd = self._input_directions(x, p)
        h = _dot(p, self.open_loop(x)) + _dot(qu, u)
        if qd:
            h = h + self.disturbance_space.optimum(qd, self.disturbance_mode)
        return h

    def partial_bounds_at(self, t, x: Sequence, params=None) -> tuple:
        """Exact local Lax-Friedrichs coefficients of the closed loop: ``|f_i(x) + G_u(x) kappa(t, x)|`` plus the
        disturbance's spread (``H`` is linear in ``p`` but for the disturbance term). Much smaller than the
        open-loop bounds where the feedback holds a state still (a heading held by a turn-rate feedback gets
        ``|d_theta|`` instead of ``omega_max + |d_theta|``), so thin closed-loop sets are not dissipated away. The
        CFL step keeps the open-loop :meth:`partial_bounds`, an upper bound for all times."""
        return _rate_bounds(self, x, self.feedback(t, x, params), ())

    def optimal_control(self, x: Sequence, p: Sequence) -> tuple:
        raise TypeError("FeedbackDynamics have no control input; the control is feedback(t, x, params).")
