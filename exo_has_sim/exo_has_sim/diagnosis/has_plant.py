"""The project's HAS model (:mod:`exo_has_sim.model`) as a plant the diagnosis fits, over windows.

A window's initial state comes from the data (:mod:`~exo_has_sim.diagnosis.plants`): the
position and, when measured, the pressure, smoothed, with the velocity (and, without a pressure
sensor, the pressure from the force balance, Eq. 8). The motor speed and the spool come from
the commands sent before the window, through the model's own speed loop and valve. Without a
load-force signal the load is one constant, fitted with the baseline, or, with the pressure
unmeasured too, a polynomial in time of each window's own (:meth:`HasPlant.predict`).

The model is integrated by the compiled integrator of :mod:`exo_has_sim.simulate` (that of
``simulate_open_loop``, at tighter tolerances, see :data:`HAS_ATOL`), every (candidate,
window) pair one of its "joints".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.polynomial import Legendre
from scipy.linalg import expm
from scipy.signal import lfilter

from exo_has_sim import model, simulate
from exo_has_sim.diagnosis.compare import Span
from exo_has_sim.diagnosis.data import Measurement
from exo_has_sim.diagnosis.effects import (
    EFFECTS,
    RELIEF_CRACK_CONDUCTANCE,
    RecordRange,
    has_effect_parameters,
)
from exo_has_sim.diagnosis.plants import (
    Candidate,
    FloatArray,
    IntArray,
    Parameter,
    Plant,
    smooth,
)
from exo_has_sim.errors import DiagnosisError
from exo_has_sim.parameters import Effects, HasParameters

GRAVITY = 9.81  # m/s^2
#: Relative tolerance of the HAS windows' integration.
HAS_RTOL = 1e-3
#: Absolute tolerances of (x [m], v [m/s], p_A [Pa], n [rad/s], spool [-], void [m^3], n_dot
#: [rad/s^2], p_B [Pa]), ten
#: times tighter than :mod:`exo_has_sim.simulate`'s defaults, which suit a plant node but not a
#: comparison with data at a sensor's resolution: where the motor speed passes zero, the spool
#: dips towards free mode and ``(1 - s) G_free p`` drains the chamber at a rate that a spool
#: error of 1e-3 changes by 60 MPa/s; at the default tolerances the simulated pressure there
#: was off by up to 0.8 MPa and the position by 0.1 mm (against a tight-tolerance run), at
#: these 60 kPa and 13 um, the level of the sensors' noise, for 1.6 times the steps.
HAS_ATOL = np.array([1e-7, 1e-5, 1e3, 1e-3, 1e-5, 1e-10, 10.0, 1e3])
#: What a candidate may set of :class:`exo_has_sim.parameters.HasParameters`: the HAS
#: baseline's re-estimated parameters and the damping ratio of its second-order motor loop.
NUISANCE = ('bulk_modulus', 'pump_leakage', 'damping', 'motor_time_constant',
            'pump_displacement', 'dead_volume', 'motor_damping_ratio', 'charge_pressure',
            'charge_stiffness', 'return_conductance', 'brake_force')
#: Relative standard uncertainty of a nuisance parameter whose parameter set states none
#: (None: no prior). The motor's speed loop and the dead volume are assumed values in the
#: project's sets (their provenance says so); the displacement is stated (paper 2.3.1: 0.4
#: mL/r), the volumetric efficiency that scales it into the flow gain is not. Bulk modulus,
#: leakage and damping are what the paper (4.2) calls hard to know: the data decide.
DEFAULT_UNCERTAINTY: dict[str, float | None] = {
    'bulk_modulus': None, 'pump_leakage': None, 'damping': None,
    'motor_time_constant': 0.3, 'pump_displacement': 0.15, 'dead_volume': 0.3,
    'return_conductance': None, 'brake_force': None, 'charge_stiffness': None}
#: Unit of the linear search of a charge pressure [Pa] (a charge may be 0 gauge).
CHARGE_SCALE = 1e5
#: Damping ratios a second-order motor loop is screened at: under- to overdamped.
SECOND_ORDER_GRID = (0.4, 0.7, 1.0, 1.5)
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


def model_air_fraction(fraction: float) -> float:
    """Convert a free-air volume fraction at atmospheric pressure to the model's parameter.

    :func:`exo_has_sim.model.effective_bulk_modulus` takes the air's share of the mixture at
    pressure p as ``a (p_atm / p_abs)^(1/1.4)``, exact for little air. A fraction alpha of the
    volume at atmospheric pressure is ``alpha / (1 - alpha)`` of the oil's volume, and the air's
    share at pressure p is ``alpha r / (1 - alpha + alpha r)`` with r that power ratio (at most
    0.18 above 1 MPa), so ``a = alpha / (1 - alpha)`` to first order in ``alpha r``: without it
    the model's parameter would read 25 % high at alpha = 0.2.
    """
    return fraction / (1.0 - fraction)


def _delayed_indices(starts: IntArray, horizon: int, lag: int) -> IntArray:
    return np.asarray(starts[None, :] - lag + np.arange(horizon)[:, None], dtype=np.int64)


class HasPlant(Plant):
    """The project's HAS model (issue 3) with nominal parameters, over windows.

    The baseline re-estimates what section 4.2 of the paper calls hard to know: the bulk
    modulus E_y, the pump leakage L_n and the damping B; without a load-force signal, also a
    constant load force. Everything else keeps its value from the parameter set.

    Outputs are the position and, when measured, the rodless pressure and the motor speed.
    In the paper's circuit a measured rod-side pressure is an input: its force A_B p_B joins
    the load. In a circuit with a rod chamber of its own (``params.circuit``) it is an output,
    the chamber's pressure a state, and the baseline also fits the charge pressure and the
    return conductance. A window's initial motor speed and spool position are not taken from
    the (noisy) speed signal but computed from the commands sent before it, through the
    model's own speed loop and valve (first-order lags), so they carry the candidate's
    transport delay.

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

        Each but the load carries a prior from the parameter set: centred on its value, as
        wide as the set's stated uncertainty (:data:`DEFAULT_UNCERTAINTY` where it states
        none), so that the baseline takes up what is error of the nominal values and leaves
        the effects what is physics.
        """
        p = self.params

        def prior(name: str) -> float | None:
            spread = p.uncertainty.get(name, DEFAULT_UNCERTAINTY.get(name))
            return None if spread is None else math.log1p(spread)

        out = [
            Parameter('bulk_modulus', 'Pa', p.bulk_modulus, 5e7, 3e9,
                      'effective bulk modulus E_y of oil, hose and seals',
                      prior=prior('bulk_modulus')),
            Parameter('pump_leakage', 'm^3/(s Pa)', p.pump_leakage, 1e-16, 1e-11,
                      'pump inner leakage coefficient L_n', prior=prior('pump_leakage'),
                      negligible_floor=True),
            Parameter('damping', 'N s/m', p.damping, 10.0, 1e5, 'viscous damping B',
                      prior=prior('damping'), negligible_floor=True),
            Parameter('motor_time_constant', 's', p.motor_time_constant,
                      p.motor_time_constant / 10.0, p.motor_time_constant * 10.0,
                      'time constant of the motor speed loop',
                      prior=prior('motor_time_constant')),
            Parameter('pump_displacement', 'm^3/rad', p.pump_displacement,
                      p.pump_displacement / 2.0, p.pump_displacement * 2.0,
                      'effective pump displacement: the flow gain, volumetric efficiency '
                      'included', prior=prior('pump_displacement')),
            Parameter('dead_volume', 'm^3', p.dead_volume, p.dead_volume / 5.0,
                      p.dead_volume * 5.0, 'oil volume of the rodless side at full retraction',
                      prior=prior('dead_volume')),
        ]
        if p.motor_damping_ratio > 0.0:  # the parameter set's loop is second order already
            out.append(self._damping_ratio(p.motor_damping_ratio, prior('motor_damping_ratio')))
        if self.speed_input:  # the measured speed drives the pump: no motor loop to fit
            out = [q for q in out if q.name not in ('motor_time_constant',
                                                    'motor_damping_ratio')]
        if self.rod_chamber:
            spread = p.uncertainty.get('charge_pressure')
            out += [
                Parameter('charge_pressure', 'Pa', p.charge_pressure, -0.05e6,
                          max(10.0 * p.charge_pressure, 2e6), 'pressure of the charge line, '
                          'accumulator or tank the low-pressure chamber returns to',
                          scale=CHARGE_SCALE, prior=None if spread is None else
                          spread * max(p.charge_pressure, CHARGE_SCALE) / CHARGE_SCALE),
                Parameter('return_conductance', 'm^3/(s Pa)', p.return_conductance,
                          p.return_conductance / 100.0, p.return_conductance * 100.0,
                          "conductance of the low-pressure chamber's return path",
                          prior=prior('return_conductance'))]
            if p.charge_stiffness > 0.0:
                out.append(Parameter('charge_stiffness', 'Pa/m', p.charge_stiffness,
                                     p.charge_stiffness / 10.0, p.charge_stiffness * 10.0,
                                     "fall of the accumulator's pressure per metre of "
                                     'extension', prior=prior('charge_stiffness')))
        if p.brake_force > 0.0 and 'brake_force' in p.uncertainty:
            # A brake known only roughly (its file states an uncertainty) is fitted; one
            # stated exactly is held.
            out.append(Parameter('brake_force', 'N', p.brake_force, p.brake_force / 20.0,
                                 p.brake_force * 20.0, 'force of the known brake',
                                 prior=prior('brake_force')))
        if self._load is None and not self.window_load:
            # Linear: a rig's load may be nil or pull (a horizontal cylinder, a spring).
            out.append(Parameter('load_force', 'N', self._load_guess, -p.peak_thrust,
                                 2.0 * p.peak_thrust, 'constant external load force pushing '
                                 'the cylinder in', scale=0.05 * p.peak_thrust))
        return tuple(out)

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
            return predicted + _moved(changes, self._window_gains(predicted, changes, span))
        changes, gains = self._linearisation(linearised_at, span)
        size = np.linalg.norm(gains[0], axis=-1)  # each window's load terms [steps]
        direction = gains[0] / np.where(size > 0.0, size, 1.0)[:, None]
        bare = super().predict(candidates, span)
        pushed = self.simulate(candidates, span.starts, span.steps, span.burn_in,
                               window_loads=direction)[:, :, span.burn_in:]
        # The candidate at the loads of the base, as its own sensitivities put them (along
        # them, one step in one simulation), less the base's sensitivities' share.
        at_guess: FloatArray = bare + size[:, None, None] * (pushed - bare) \
            - _moved(changes, gains)
        return at_guess + _moved(changes, self._window_gains(at_guess, changes, span))

    def _window_gains(self, predicted: FloatArray, changes: FloatArray,
                      span: Span) -> FloatArray:
        """Each window's load terms [steps] that fit its position best, within the bounds.

        ``predicted`` at the load guess, ``changes`` per term (:meth:`_load_sensitivities`,
        or one candidate's for all); shape (candidates, windows, terms).
        """
        step = WINDOW_LOAD_STEP * self.params.peak_thrust
        terms = WINDOW_LOAD_DEGREE + 1
        error = self.measured(span)[None, ..., 0] - predicted[..., 0]
        basis = changes[..., 0, :]  # the position's sensitivities, (..., horizon, term)
        normal = np.einsum('...ki,...kj->...ij', basis, basis)
        right = np.einsum('...ki,...k->...i', basis, error)
        # A window where the load does not move the position (cavitation, a stop) keeps
        # the guess: the ridge is negligible against any sensitivity that counts.
        ridge = 1e-12 * np.trace(normal, axis1=-2, axis2=-1)[..., None, None] + 1e-300
        with np.errstate(invalid='ignore', over='ignore'):
            gains = np.linalg.solve(np.broadcast_to(normal + ridge * np.eye(terms),
                                                    (*right.shape, terms)),
                                    right[..., None])[..., 0]
        gains = np.where(np.isfinite(gains), gains, 0.0)
        # The load across each window at a few instants, and the constant fit where it leaves
        # what the cylinder can carry.
        low, high = self.load_bounds()
        shapes = np.stack([Legendre.basis(d)(np.linspace(-1.0, 1.0, 9)) for d in range(terms)])
        path = self._load_guess + step * gains @ shapes
        outside = (path.min(axis=-1) < low) | (path.max(axis=-1) > high)
        if np.any(outside):
            level = right[..., 0] / (normal[..., 0, 0] + ridge[..., 0, 0])
            level = np.clip(level, (low - self._load_guess) / step,
                            (high - self._load_guess) / step)
            constant = np.zeros_like(gains)
            constant[..., 0] = level
            gains = np.where(outside[..., None], constant, gains)
        return np.asarray(gains, dtype=float)

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
        return {'second_order_motor': (self._damping_ratio(0.7, None, SECOND_ORDER_GRID),)}

    @staticmethod
    def _damping_ratio(start: float, prior: float | None,
                       grid: tuple[float, ...] = ()) -> Parameter:
        return Parameter('motor_damping_ratio', '-', start, 0.1, 5.0,
                         'damping ratio of the second-order motor speed loop', prior=prior,
                         grid=grid)

    @property
    def effects(self) -> tuple[str, ...]:
        """Every effect of the library that this plant does not have already.

        Not a delay with the measured speed as the input, nor a braking load where the
        parameter set has a brake (its force is then the baseline's).
        """
        return tuple(e for e in ('coulomb_friction', 'braking_load', 'pump_deadzone',
                                 'transport_delay', 'quadratic_leakage', 'relief_valve',
                                 'entrained_air')
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
        """Parameter set of a candidate and its transport delay [s]."""
        p = self.params
        sizes = {k: float(values[k]) for k in ('coulomb_friction', 'pump_deadzone',
                                               'quadratic_leakage') if k in values}
        if 'entrained_air' in values:
            sizes['entrained_air'] = model_air_fraction(float(values['entrained_air']))
        if 'relief_crack_pressure' in values:
            sizes['relief_crack_pressure'] = float(values['relief_crack_pressure'])
            sizes['relief_crack_conductance'] = float(
                values.get('relief_crack_conductance', RELIEF_CRACK_CONDUCTANCE))
        nuisance: dict[str, Any] = {name: float(values.get(name, getattr(p, name)))
                                    for name in NUISANCE}
        params = replace(p, **nuisance, effects=Effects(**sizes))
        return params, float(values.get('transport_delay', 0.0))

    def drive(self, delay: float, time_constant: float | None = None,
              damping_ratio: float | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Motor speed [rad/s], its rate [rad/s^2] and spool position [-] at every sample.

        The commands, delayed by ``delay`` (to the nearest sample) and held, through the speed
        loop of ``time_constant`` [s] and ``damping_ratio`` (defaults: the parameter set's;
        first order for a ratio of 0, else second order as :mod:`exo_has_sim.model` has it;
        exact for held inputs; the switched circuit's one-way motor follows their size), or
        the measured speed itself with :attr:`speed_input`. The compact valve's spool follows
        the model's valve law (:func:`exo_has_sim.model.spool_target`, driven by the speed and
        the measured or load-bearing pressure), the switched circuit's direction valve the
        command's sign (held within ``valve_release_speed``), each through its first-order
        lag, sample by sample; the closed circuit has no valve to move (1). The drive's
        torque limit is not applied here: a start state that it would have held back is
        forgotten in the burn-in.
        """
        params = self.params
        tau = params.motor_time_constant if time_constant is None else time_constant
        zeta = params.motor_damping_ratio if damping_ratio is None else damping_ratio
        lag = round(delay / self.measurement.period)
        key = (lag, tau, zeta)
        if key not in self._drive_cache:
            if len(self._drive_cache) >= DRIVE_CACHE:  # a fit's latest points matter
                self._drive_cache.pop(next(iter(self._drive_cache)))
            period = self.measurement.period
            command = np.concatenate((np.full(lag, self._u[0]), self._u[:len(self._u) - lag]))
            command = np.clip(command, -params.motor_speed_max, params.motor_speed_max)
            one_way = params.circuit == 'switched'
            if self.speed_input:
                speed, rate = np.abs(command) if one_way else command, np.zeros(len(command))
            else:
                asked = np.abs(command) if one_way else command
                # The speed at sample k + 1 results from the command held over sample k.
                if zeta > 0.0:
                    response, rate = _second_order(asked, period, tau, zeta)
                    rate = np.concatenate(([0.0], rate[:-1]))
                else:
                    response, rate = _first_order(asked, period, tau), np.zeros(len(asked))
                speed = np.concatenate(([asked[0]], response[:-1]))
            gain = 1.0 - math.exp(-period / params.valve_time_constant)
            spool = np.ones(len(speed))
            if one_way:
                s = 1.0
                for k in range(len(speed)):
                    spool[k] = s
                    if abs(command[k]) > params.valve_release_speed:
                        s += gain * (math.copysign(1.0, command[k]) - s)
            elif params.circuit != 'closed':
                if self._p is not None:
                    pressure = self._p
                else:
                    load = self._load if self._load is not None \
                        else self._load_guess + self._rod_force
                    pressure = load / params.area_a
                prm = model.pack(params)
                s = 1.0
                for k in range(len(speed)):
                    spool[k] = s
                    s += gain * (model.spool_target(speed[k], pressure[k], s, prm) - s)
            self._drive_cache[key] = (speed, rate, spool)
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
            shapes = np.stack([Legendre.basis(d)(np.linspace(-1.0, 1.0, horizon))
                               for d in range(window_loads.shape[1])])
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


def _moved(changes: FloatArray, gains: FloatArray) -> FloatArray:
    """Return the outputs' change by windows' load terms.

    ``changes`` per term, shape (..., horizon, output, term); ``gains``, (..., term).
    """
    return np.asarray(np.einsum('...hoi,...i->...ho', changes, gains), dtype=float)


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


def _second_order(values: FloatArray, period: float, time_constant: float,
                  damping_ratio: float) -> tuple[FloatArray, FloatArray]:
    """Response and rate at the samples of the second-order speed loop to a held input.

    ``n'' = w^2 (u - n) - 2 zeta w n'`` with ``w = 2 zeta / time_constant``
    (:func:`exo_has_sim.model.rhs`), from rest at the first input, discretised exactly for an
    input held over each period.
    """
    omega = 2.0 * damping_ratio / time_constant
    a = np.array([[0.0, 1.0], [-omega * omega, -2.0 * damping_ratio * omega]])
    b = np.array([0.0, omega * omega])
    augmented = np.zeros((3, 3))
    augmented[:2, :2], augmented[:2, 2] = a * period, b * period
    transition = expm(augmented)
    phi, gamma = transition[:2, :2], transition[:2, 2]
    state = np.array([values[0], 0.0])
    out = np.empty((len(values), 2))
    for k, u in enumerate(values):
        state = phi @ state + gamma * u
        out[k] = state
    return out[:, 0], out[:, 1]


def _first_order(values: FloatArray, period: float, time_constant: float) -> FloatArray:
    """Response at the samples of a first-order lag to an input held over each period."""
    alpha = 1.0 - math.exp(-period / time_constant)
    out = lfilter([alpha], [1.0, alpha - 1.0], values, zi=[(1.0 - alpha) * values[0]])
    return np.asarray(out[0], dtype=float)
