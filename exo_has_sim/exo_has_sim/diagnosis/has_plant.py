"""The project's HAS model (:mod:`exo_has_sim.model`) as a plant the diagnosis fits, over windows.

A window's initial state comes from the data (:mod:`~exo_has_sim.diagnosis.plants`): the
position and, when measured, the pressure, smoothed, with the velocity (and, without a pressure
sensor, the pressure from the force balance, Eq. 8), and the measured motor speed. The spool,
and a motor speed not measured, come from the commands sent before the window, through the
model's own speed loop and valve. Without a load-force signal the load is one constant, fitted
with the baseline, or, with the pressure unmeasured too, a polynomial in time of each window's
own (:meth:`HasPlant.predict`).

The model is integrated by the compiled integrator of :mod:`exo_has_sim.integrator` (that of
``simulate_open_loop``, at tighter tolerances, see :data:`HAS_ATOL`), every (candidate,
window) pair one of its "joints".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from exo_has_sim import model, simulate
from exo_has_sim.diagnosis.compare import Span
from exo_has_sim.diagnosis.data import Measurement
from exo_has_sim.diagnosis.effects import (
    EFFECTS,
    RecordRange,
    effects_of,
    has_effect_parameters,
)
from exo_has_sim.diagnosis.has_baseline import (
    SECOND_ORDER_GRID,
    baseline_parameters,
    candidate_parameters,
    damping_ratio_parameter,
)
from exo_has_sim.diagnosis.has_drive import drive_histories
from exo_has_sim.diagnosis.plants import (
    Candidate,
    FloatArray,
    IntArray,
    Parameter,
    WindowedModel,
    smooth,
)
from exo_has_sim.diagnosis.window_loads import load_shapes, moved, window_gains
from exo_has_sim.errors import DiagnosisError
from exo_has_sim.parameters import Effects, HasParameters

GRAVITY = 9.81  # m/s^2
#: Relative tolerance of the HAS windows' integration.
HAS_RTOL = 1e-3
#: Absolute tolerances of (x [m], v [m/s], p_A [Pa], n [rad/s], spool [-], void [m^3], n_dot
#: [rad/s^2], p_B [Pa]), ten times tighter than :mod:`exo_has_sim.integrator`'s defaults,
#: which suit a plant node but not a comparison with data at a sensor's resolution: where the
#: motor speed passes zero, the spool dips towards free mode and ``(1 - s) G_free p`` drains
#: the chamber at a rate that a spool error of 1e-3 changes by 60 MPa/s. ROS34PW2 on 80 of the
#: diagnosis's integrations, worst sample against a run 1000 times tighter (bench/integrator.py):
#: ten times looser 178 um and 0.95 MPa off, at these 41 um and 0.36 MPa for 1.5 times the steps
#: (candidates that cavitate and ring in an end stop; a typical window is within a few um).
HAS_ATOL = np.array([1e-7, 1e-5, 1e3, 1e-3, 1e-5, 1e-10, 10.0, 1e3])
#: Motor speed and spool histories kept (one per delay and time constant a fit tried).
DRIVE_CACHE = 32
#: Load step [share of the peak thrust] of the simulations that give a window's sensitivity
#: to an unmeasured load (:meth:`HasPlant.predict`).
WINDOW_LOAD_STEP = 0.2
#: Degree of the polynomial in time that an unmeasured load takes across each window: a level,
#: a slope and a bend. A squat's load swings with the depth at 0.5 Hz, a third of a period
#: per window, and the bend a line leaves of it is matched by a spurious delay of 11-15 ms
#: (bench/README.md, "Position only").
WINDOW_LOAD_DEGREE = 2
#: Window-load linearisations kept (:meth:`HasPlant.predict`): a fit's latest points.
LINEARISATIONS_KEPT = 4
#: Most joints (candidate x window pairs) integrated in one call, which bounds the memory of
#: the state history (a call holds horizon x joints x model.N_STATE floats).
MAX_JOINTS = 2048


def _delayed_indices(starts: IntArray, horizon: int, lag: int) -> IntArray:
    return np.asarray(starts[None, :] - lag + np.arange(horizon)[:, None], dtype=np.int64)


class HasPlant(WindowedModel):
    """The project's HAS model (issue 3) with nominal parameters, over windows.

    The baseline re-estimates what section 4.2 of the paper calls hard to know: the bulk
    modulus E_y, the pump leakage L_n and the damping B; without a load-force signal, also a
    constant load force. Everything else keeps its value from the parameter set.

    Outputs are the position and, when measured, the rodless pressure and the motor speed.
    In the paper's circuit a measured rod-side pressure is an input: its force A_B p_B joins
    the load. In a circuit with a rod chamber of its own (``params.circuit``) it is an output,
    the chamber's pressure a state, and the baseline also fits the charge pressure and the
    return conductance. A window's initial motor speed is the measured one where the record
    has it, as it is: computed from the commands sent before the window, it was up to 18
    rad/s off the plant's on a session's bag (the commands on the record's grid are not those
    of the plant's ticks), and smoothed, up to 8.6 rad/s where it changes fast; a sensor's
    noise in it the speed loop forgets within the burn-in (its time constants), as it does
    not the position's. The spool position, and a motor speed not measured, are computed from
    the commands sent before the window, through the model's own speed loop and valve
    (first-order lags), with the candidate's transport delay.

    With ``speed_input`` the measured motor speed drives the pump instead of the command
    through the motor's loop, so that the hydraulics are judged apart from the motor (a drive
    that cannot follow its command, a torque limit): the motor's lag, order and delay are then
    no part of the model, and the motor speed no output.

    Parameters
    ----------
    measurement : Measurement
        The data (plant ``'has'``).
    params : HasParameters
        Nominal parameters (joint type's set or a parameters file), effects off.
    load_mass : float or None
        Mass moved by the cylinder [kg] (replaces ``params.load_mass``).
    constant_load : bool
        The user's word that an unmeasured load does not vary (a bench test with a fixed
        mass): it then makes the effects that act through the pressure identifiable from
        the position alone (:attr:`unidentifiable`).
    speed_input : bool
        Drive the pump with the measured ``motor_speed`` (which must be in the record).

    Raises
    ------
    DiagnosisError
        For ``speed_input`` without a motor speed in the record.

    """

    kind = 'has'

    def __init__(self, measurement: Measurement, params: HasParameters,
                 load_mass: float | None = None, constant_load: bool = False,
                 speed_input: bool = False) -> None:
        if speed_input and not measurement.has('motor_speed'):
            raise DiagnosisError('driving the pump by the measured motor speed needs a '
                                 'motor_speed column')
        self.measurement = measurement
        self.constant_load = constant_load
        self.speed_input = speed_input
        base = params if load_mass is None else replace(params, load_mass=load_mass)
        self.params = replace(base, effects=Effects())
        if measurement.has('load_force') and self.params.brake_force > 0.0:
            # A measured load is the whole external force on the rod, a brake's included.
            self.params = replace(self.params, brake_force=0.0)
        self.rod_chamber = self.params.circuit != 'paper'
        measured = ['pressure_a', 'motor_speed']
        if self.rod_chamber:
            measured.insert(1, 'pressure_b')
        if speed_input:
            measured.remove('motor_speed')
        self.outputs = ('position', *(name for name in measured if measurement.has(name)))
        period = measurement.period
        self._x = smooth(measurement.position, period)
        self._v = smooth(measurement.position, period, 1)
        self._a = smooth(measurement.position, period, 2)
        self._p = smooth(measurement.optional['pressure_a'], period) \
            if measurement.has('pressure_a') else None
        self._p_b = smooth(measurement.optional['pressure_b'], period) \
            if measurement.has('pressure_b') else None
        # A window starts from the measured motor speed (the one-way motor's is its size), and
        # a second-order loop from its smoothed rate; the measured speed as the input is its
        # own start.
        self._n: tuple[FloatArray, FloatArray] | None = None
        if measurement.has('motor_speed') and not speed_input:
            speed = measurement.optional['motor_speed']
            if self.params.circuit == 'switched':
                speed = np.abs(speed)
            self._n = speed, smooth(speed, period, 1)
        # The paper's model has the rod chamber at the tank's (atmospheric) pressure; where the
        # rod-side pressure is measured, its force A_B p_B acts with the load (an elastic tank
        # kept above atmospheric, the pressure drop of the return line). A circuit with a rod
        # chamber of its own has that pressure as a state.
        self._rod_force = self._p_b * self.params.area_b \
            if self._p_b is not None and not self.rod_chamber else np.zeros(len(self._x))
        self._load: FloatArray | None = smooth(measurement.optional['load_force'], period) \
            + self._rod_force if measurement.has('load_force') else None
        if self._p is not None:
            rod = self._rod_force if not self.rod_chamber else self.params.area_b * (
                self._p_b if self._p_b is not None else self.params.charge_pressure)
            guess = float(np.median(self._p * self.params.area_a - rod))
        else:
            guess = self.params.moving_mass * GRAVITY
        self._load_guess = float(np.clip(guess, -0.9 * self.params.peak_thrust,
                                         1.9 * self.params.peak_thrust))
        self.record = RecordRange(
            None if self._p is None else float(np.percentile(self._p, 99)),
            None if self._p is None else float(np.percentile(np.abs(
                self.params.area_a * self._p - self.params.area_b * (
                    self._p_b if self._p_b is not None else 0.0)), 99)))
        self._u = np.ascontiguousarray(measurement.input, dtype=float)
        if speed_input:
            self._u = np.ascontiguousarray(measurement.optional['motor_speed'], dtype=float)
            if self.params.circuit == 'switched' and np.min(self._u) >= 0.0 \
                    and np.min(measurement.input) < 0.0:
                # A one-way motor's speed logged without the direction: the command's sign
                # is the direction valve's side.
                self._u = np.ascontiguousarray(self._u * np.where(measurement.input < 0.0,
                                                                  -1.0, 1.0))
        # The switched circuit's motor turns one way; a logged speed signed by the direction
        # valve's side (as the command is) is compared signed, an unsigned one as it is.
        self._signed_speed = self.params.circuit == 'switched' \
            and measurement.has('motor_speed') \
            and float(np.min(measurement.optional['motor_speed'])) < 0.0
        self._drive_cache: dict[tuple[int, float, float],
                                tuple[FloatArray, FloatArray, FloatArray]] = {}
        self._linearisations: dict[tuple[Any, ...], tuple[FloatArray, FloatArray]] = {}

    def restructured(self, circuit: str, speed_input: bool,
                     brake_force: float = 0.0) -> HasPlant:
        """Return the plant of the same record with another circuit, pump input or brake.

        Going from the paper's circuit to one with a rod chamber of its own, the charge
        pressure starts where the record's lower chamber sits (the median of the lower of the
        two measured pressures, or the rodless one's 5th percentile), the file's value being
        the paper's atmospheric tank. A positive ``brake_force`` [N] gives it a brake of that
        size to start from (fitted in the baseline); 0 keeps the parameter set's.
        """
        params = replace(self.params, circuit=circuit)
        if brake_force > 0.0:  # estimated from the record: fitted, within a factor 2 or so
            params = replace(params, brake_force=brake_force,
                             uncertainty={**params.uncertainty, 'brake_force': 0.5})
        if circuit != 'paper' and not self.rod_chamber and self._p is not None:
            if self._p_b is not None:
                # The lower chamber drains to the charge: its pressure against the extension
                # gives the charge pressure at mid stroke and how an accumulator's falls.
                low = np.minimum(self._p, self._p_b)
                slope, level = np.polyfit(self._x - 0.5 * params.stroke, low, 1)
                params = replace(params, charge_pressure=max(float(level), 0.0),
                                 charge_stiffness=max(-float(slope), 0.0))
            else:
                params = replace(params, charge_pressure=max(
                    float(np.percentile(self._p, 5)), 0.0))
        return HasPlant(self.measurement, params, None, self.constant_load, speed_input)

    @property
    def baseline(self) -> tuple[Parameter, ...]:
        """E_y, L_n, B, motor lag, flow gain, dead volume (and a constant unmeasured load).

        :func:`~exo_has_sim.diagnosis.has_baseline.baseline_parameters`: the load's level is
        fitted where it is neither measured nor each window's own (:attr:`window_load`).
        """
        load_guess = self._load_guess if self._load is None and not self.window_load else None
        return baseline_parameters(self.params, self.speed_input, load_guess)

    @property
    def limit_kind(self) -> str:
        """``'rodless'`` where the pump feeds the rodless chamber alone, else ``'either'``.

        The detection limits' margins were measured on a truth plant of each kind
        (:data:`exo_has_sim.diagnosis.limits.LIMIT_MARGIN`), from records with the rodless
        pressure: without it, ``'no_pressure'``.
        """
        if not self.measurement.has('pressure_a'):
            return 'no_pressure'
        return 'rodless' if self.params.circuit in ('paper', 'two_chamber') else 'either'

    @property
    def window_load(self) -> bool:
        """Whether each window estimates a load of its own (:meth:`predict`).

        So it does when neither the pressure nor the load is measured and the user has not
        said that the load is constant: a load that varies unmeasured (a gait's) would
        otherwise leave its own misfit to the effects that stay identifiable.
        """
        return self._p is None and self._load is None and not self.constant_load

    @property
    def linearises(self) -> bool:
        """Whether :meth:`predict` linearises at ``linearised_at``: with windows' loads."""
        return self.window_load

    def predict(self, candidates: Sequence[Candidate], span: Span,
                linearised_at: Candidate | None = None) -> FloatArray:
        """Predict the outputs at the scored samples, a window's load its own if unmeasured.

        With :attr:`window_load`, each window takes the load, a polynomial in time of degree
        :data:`WINDOW_LOAD_DEGREE` across the window, that fits its measured position best,
        as it takes its initial state from the data: the prediction at the load guess is
        moved along the window's sensitivities to each Legendre term (one more simulation
        per term, the load raised by :data:`WINDOW_LOAD_STEP` of the peak thrust times the
        term, the start state with it) by the least-squares step, linear in the load as the
        leakage and the compression are in the pressure.

        ``linearised_at``: the candidates near this one (a Jacobian's steps) are predicted
        by Kaufman's variable projection: each one's sensitivities are taken along this
        one's windows' loads only, in one simulation with those loads scaled to one step,
        and the loads are re-fitted along this one's sensitivities (two simulations each,
        against one per term more). It drops only the change of the sensitivities times the
        change of the loads, second order; dropping the change of the sensitivities
        altogether (one simulation) missed a third of the bulk modulus's effect on a loaded
        hip's record. Differences are to be taken from this one linearised alike.

        The load so found is held to what the cylinder can carry: between what the rodless
        chamber holds at its cavitation pressure and at the relief setting
        (:meth:`load_bounds`). A window whose best load leaves that range takes the constant
        load within it that fits best instead: unbounded, the loads made any record fit, even
        a rig's whose circuit the model does not have (-250 to +950 kN against +-7 kN
        measured, and the nominal model at 99.7 %).
        """
        if not self.window_load:
            return super().predict(candidates, span)
        if linearised_at is None:
            predicted = super().predict(candidates, span)
            changes = self._load_sensitivities(candidates, span, predicted)
            return predicted + moved(changes, self._window_gains(predicted, changes, span))
        changes, gains = self._linearisation(linearised_at, span)
        size = np.linalg.norm(gains[0], axis=-1)  # each window's load terms [steps]
        direction = gains[0] / np.where(size > 0.0, size, 1.0)[:, None]
        bare = super().predict(candidates, span)
        pushed = self.simulate(candidates, span.starts, span.steps, span.burn_in,
                               window_loads=direction)[:, :, span.burn_in:]
        # The candidate at the loads of the base, as its own sensitivities put them (along
        # them, one step in one simulation), less the base's sensitivities' share.
        at_guess: FloatArray = bare + size[:, None, None] * (pushed - bare) \
            - moved(changes, gains)
        return at_guess + moved(changes, self._window_gains(at_guess, changes, span))

    def _window_gains(self, predicted: FloatArray, changes: FloatArray,
                      span: Span) -> FloatArray:
        """Each window's load terms [steps] that fit its position best, within the bounds.

        ``predicted`` at the load guess, ``changes`` per term (:meth:`_load_sensitivities`,
        or one candidate's for all); shape (candidates, windows, terms).
        """
        error = self.measured(span)[None, ..., 0] - predicted[..., 0]
        return window_gains(error, changes, self._load_guess,
                            WINDOW_LOAD_STEP * self.params.peak_thrust, self.load_bounds())

    def _load_sensitivities(self, candidates: Sequence[Candidate], span: Span,
                            predicted: FloatArray) -> FloatArray:
        """Each candidate's change of the outputs per window-load term (:meth:`predict`).

        Shape (candidates, windows, horizon, outputs, terms).
        """
        terms = WINDOW_LOAD_DEGREE + 1
        pushed = np.stack([
            self.simulate(candidates, span.starts, span.steps, span.burn_in,
                          window_loads=np.tile(np.eye(terms)[degree], (len(span.starts), 1))
                          )[:, :, span.burn_in:]
            for degree in range(terms)])
        return np.moveaxis(pushed - predicted[None], 0, -1)  # (..., horizon, output, term)

    def _linearisation(self, candidate: Candidate,
                       span: Span) -> tuple[FloatArray, FloatArray]:
        """One candidate's load sensitivities and windows' load terms, the last few kept.

        Shapes (1, windows, horizon, outputs, terms) and (1, windows, terms): a fit's
        Jacobian is linearised at the point it evaluated last.
        """
        key = (tuple(sorted(candidate.items())), span.starts.tobytes(), span.steps,
               span.burn_in)
        if key not in self._linearisations:
            predicted = super().predict([candidate], span)
            changes = self._load_sensitivities([candidate], span, predicted)
            gains = self._window_gains(predicted, changes, span)
            if len(self._linearisations) >= LINEARISATIONS_KEPT:
                del self._linearisations[next(iter(self._linearisations))]
            self._linearisations[key] = (changes, gains)
        return self._linearisations[key]

    def load_bounds(self) -> tuple[float, float]:
        """Return the external load [N] the cylinder can carry: cavitation to relief.

        ``A_A p - A_B p_B`` at the cavitation pressure and at the relief setting (the rod
        side at the charge pressure), widened by the peak thrust's tenth for the force the
        motion itself takes (mass, damping).
        """
        p = self.params
        rod = p.area_b * p.charge_pressure if self.rod_chamber else 0.0
        margin = 0.1 * p.peak_thrust
        return (p.area_a * p.cavitation_pressure - rod - margin,
                p.area_a * p.relief_pressure - rod + margin)

    @property
    def alternatives(self) -> dict[str, tuple[Parameter, ...]]:
        """A second-order motor speed loop, when the parameter set's is first order.

        A drive's velocity loop (a PI controller on the motor's inertia) is at least second
        order; fitted with a first-order lag, its delayed start looks like a transport delay.
        """
        if self.params.motor_damping_ratio > 0.0 or self.speed_input:
            return {}
        return {'second_order_motor': (damping_ratio_parameter(0.7, None, SECOND_ORDER_GRID),)}

    @property
    def effects(self) -> tuple[str, ...]:
        """Every effect of the library that this plant does not have already.

        Not a delay with the measured speed as the input, nor a braking load where the
        parameter set has a brake (its force is then the baseline's).
        """
        return tuple(e for e in effects_of(self.kind)
                     if not (self.speed_input and e == 'transport_delay')
                     and not (self.params.brake_force > 0.0 and e == 'braking_load'))

    @property
    def unidentifiable(self) -> dict[str, str]:
        """The effects that act through the pressure, when neither it nor the load is known.

        The position tells only the net flow into the rodless chamber, ``A_A v``; the pump's
        flow is known from the command, and the rest, leakage and compression, is a function
        of the pressure ``p``. Without a pressure signal, ``p`` follows from the force balance
        ``A_A p = M a + B v + F_friction + F_load``, so an unmeasured load that varies can
        make any pressure history: a friction force is then a different load, and any other
        flow law of the pressure (a quadratic leakage, a cracked valve, a softer oil) is
        matched by a different pressure, hence a different load. Only the flow path from the
        command to the pump (dead zone, delay, speed loop) stays identifiable. A user who
        knows the load to be constant says so (``constant_load``): one level is then fitted
        and every effect tried.
        """
        if not self.window_load:  # the same records: pressure or load known, or constant
            if self.params.brake_force > 0.0 and any(p.name == 'brake_force'
                                                     for p in self.baseline):
                return {'coulomb_friction': (
                    "a seal's friction resists the motion as the brake the parameter set "
                    "declares does, whose force the baseline fits: it cannot be told from "
                    'the brake (record the load_force, or state the brake without '
                    'uncertainty)')}
            return {}
        why = ('it acts on the motion only through the rodless pressure, and with neither '
               'pressure_a nor load_force measured a load that varies unmeasured would make '
               'the same record; record either, or state that the load is constant '
               '(--constant-load)')
        return {effect: why for effect in self.effects if EFFECTS[effect].through_pressure}

    def effect_parameters(self, effect: str) -> tuple[Parameter, ...]:
        """Parameters of a HAS effect (:mod:`exo_has_sim.diagnosis.effects`) or structure."""
        alternatives = self.alternatives
        if effect in alternatives:
            return alternatives[effect]
        return has_effect_parameters(effect, self.params, self.record)

    def candidate_parameters(self, values: Candidate) -> tuple[HasParameters, float]:
        """Parameter set of a candidate and its transport delay [s].

        :func:`~exo_has_sim.diagnosis.has_baseline.candidate_parameters` on the plant's set.
        """
        return candidate_parameters(self.params, values)

    def drive(self, delay: float, time_constant: float | None = None,
              damping_ratio: float | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Motor speed [rad/s], its rate [rad/s^2] and spool position [-] at every sample.

        The commands, delayed by ``delay`` (to the nearest sample) and held, through the speed
        loop of ``time_constant`` [s] and ``damping_ratio`` (defaults: the parameter set's), or
        the measured speed itself with :attr:`speed_input`, and the valve, the compact one's
        law driven by the speed and the measured or load-bearing pressure
        (:func:`~exo_has_sim.diagnosis.has_drive.drive_histories`); the last
        :data:`DRIVE_CACHE` kept. The drive's torque limit is not applied here: a start state
        that it would have held back is forgotten in the burn-in.
        """
        params = self.params
        tau = params.motor_time_constant if time_constant is None else time_constant
        zeta = params.motor_damping_ratio if damping_ratio is None else damping_ratio
        lag = round(delay / self.measurement.period)
        key = (lag, tau, zeta)
        if key not in self._drive_cache:
            if len(self._drive_cache) >= DRIVE_CACHE:  # a fit's latest points matter
                self._drive_cache.pop(next(iter(self._drive_cache)))
            if self._p is not None:
                pressure = self._p
            else:
                load = self._load if self._load is not None \
                    else self._load_guess + self._rod_force
                pressure = load / params.area_a
            self._drive_cache[key] = drive_histories(self._u, lag, params,
                                                     self.measurement.period, tau, zeta,
                                                     self.speed_input, pressure)
        return self._drive_cache[key]

    def initial_states(self, params: HasParameters, delay: float, load: FloatArray,
                       starts: IntArray) -> FloatArray:
        """Return the initial state of each window, from the smoothed measurement."""
        y0 = np.zeros((len(starts), model.N_STATE))
        y0[:, model.X] = self._x[starts]
        y0[:, model.V] = self._v[starts]
        if self.rod_chamber:
            y0[:, model.PB] = self._p_b[starts] if self._p_b is not None \
                else params.charge_pressure - params.charge_stiffness * (
                    np.clip(self._x[starts], 0.0, params.stroke) - 0.5 * params.stroke)
        if self._p is not None:
            y0[:, model.PA] = self._p[starts]
        else:
            # Eq. 8 solved for the pressure that gives the measured acceleration.
            v = self._v[starts]
            force = params.moving_mass * self._a[starts] + params.damping * v + load \
                + params.area_b * y0[:, model.PB]
            fc = params.effects.coulomb_friction
            if fc:
                force += fc * np.tanh(v / params.effects.friction_smoothing_velocity)
            if params.brake_force:
                force += params.brake_force * np.tanh(v / params.brake_velocity)
            y0[:, model.PA] = np.maximum(force / params.area_a, params.cavitation_pressure)
        # The drive's histories at the whole periods either side of the delay, weighed by
        # where it lies between them: taken at the nearest alone, a window's start jumped
        # where the delay crossed half a period, and a delay's fit stopped there (7.46 ms
        # against 8 at 200 Hz).
        whole = math.floor(delay / self.measurement.period + 1e-9)
        share = delay / self.measurement.period - whole
        for lag, weight in ((whole, 1.0 - share), (whole + 1, share)):
            if weight <= 0.0:
                continue
            speed, rate, spool = self.drive(lag * self.measurement.period,
                                            params.motor_time_constant,
                                            params.motor_damping_ratio)
            y0[:, model.N] += weight * speed[starts]
            y0[:, model.NDOT] += weight * rate[starts]
            y0[:, model.S] += weight * spool[starts]
        if self._n is not None:
            y0[:, model.N] = self._n[0][starts]
            y0[:, model.NDOT] = self._n[1][starts] if params.motor_damping_ratio > 0.0 else 0.0
        return y0

    def simulate(self, candidates: Sequence[Candidate], starts: IntArray, horizon: int,
                 burn_in: int = 0, window_loads: FloatArray | None = None) -> FloatArray:
        """Predict the outputs over the windows for each candidate.

        The burn-in is simulated like the rest: the stiff hydraulics forget an imperfect
        initial velocity within it. ``window_loads``: each window's load terms [steps of
        :data:`WINDOW_LOAD_STEP` of the peak thrust] added to the load guess, shape
        (windows, terms) (:meth:`predict`).
        """
        starts = np.asarray(starts, dtype=np.int64)
        if starts.min() < self.first_start or starts.max() + horizon >= self.measurement.samples:
            raise DiagnosisError('a window reaches outside the record')
        out = np.empty((len(candidates), len(starts), horizon, len(self.outputs)))
        chunk = max(1, MAX_JOINTS // len(starts))
        for first in range(0, len(candidates), chunk):
            out[first:first + chunk] = self._simulate_chunk(candidates[first:first + chunk],
                                                            starts, horizon, window_loads)
        return out

    def _simulate_chunk(self, candidates: Sequence[Candidate], starts: IntArray,
                        horizon: int, window_loads: FloatArray | None = None) -> FloatArray:
        period = self.measurement.period
        windows = len(starts)
        extra = None
        if window_loads is not None:
            shapes = load_shapes(window_loads.shape[1], horizon)
            extra = WINDOW_LOAD_STEP * self.params.peak_thrust * (window_loads @ shapes).T
        packed, delays, commands, loads, states = [], [], [], [], []
        for values in candidates:
            params, delay = self.candidate_parameters(values)
            lag = math.floor(delay / period + 1e-9)
            # The simulator delays by the fraction of a period; whole periods shift the
            # commands here, so that a window sees the commands sent before it.
            packed.append(model.pack(params, self.speed_input))
            delays.append(delay - lag * period)
            commands.append(self._u[_delayed_indices(starts, horizon, lag)])
            if self._load is not None:
                load = self._load[_delayed_indices(starts, horizon, 0)]
                start_load = self._load[starts]
            else:
                level = float(values.get('load_force', self._load_guess))
                load = level + self._rod_force[_delayed_indices(starts, horizon, 0)]
                start_load = level + self._rod_force[starts]
                if extra is not None:  # the windows' own loads (predict)
                    load = load + extra
                    start_load = start_load + extra[0]
            loads.append(load)
            states.append(self.initial_states(params, delay, start_load, starts))
        states_out = _integrate(np.repeat(np.stack(packed), windows, axis=0),
                                np.repeat(delays, windows), np.concatenate(states),
                                np.concatenate(commands, axis=1), np.concatenate(loads, axis=1),
                                period)
        shape = (len(candidates), windows, horizon)
        index = {'position': model.X, 'pressure_a': model.PA, 'pressure_b': model.PB,
                 'motor_speed': model.N}
        out = [np.moveaxis(states_out[1:, :, index[name]], 0, 1).reshape(shape)
               for name in self.outputs]
        if 'motor_speed' in self.outputs and self._signed_speed:
            # A one-way motor's speed, signed as the logger signs it: by the command it sent
            # at that sample (the drive acts on it a transport delay later).
            k = self.outputs.index('motor_speed')
            sent = self._u[_delayed_indices(starts, horizon, 0)]
            sign = np.where(np.tile(sent, (1, len(candidates))) < 0.0, -1.0, 1.0)
            out[k] = out[k] * np.moveaxis(sign, 0, 1).reshape(shape)
        return np.stack(out, axis=-1)


def _integrate(packed: FloatArray, delay: FloatArray, y0: FloatArray, commands: FloatArray,
               loads: FloatArray, period: float) -> FloatArray:
    """Integrate N joints open loop at :data:`HAS_ATOL`, :data:`HAS_RTOL`.

    ``packed`` holds each joint's :func:`exo_has_sim.model.pack` row and ``delay`` its
    transport delay [s] (see :func:`exo_has_sim.simulate.integrate_packed`).

    Raises
    ------
    SimulationError
        If a joint diverged.

    """
    return simulate.integrate_packed(packed, delay, y0, commands, loads, period,
                                     rtol=HAS_RTOL, atol=HAS_ATOL)

