"""The design search (issue 26): requirements computed two ways, and the shipped designs."""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim.design_check import design_check, design_margins, main
from exo_has_sim.design_search import (
    DESIGN_MASS,
    SPEED_SHARE,
    STRIDE_FREQUENCY,
    Design,
    demand,
    margins,
    motions,
    search,
)
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import GRAVITY, LOAD_HEIGHT, SHANK_LENGTH, THIGH_LENGTH, squat_moments
from exo_has_sim.parameters import load_parameters

CONFIG = Path(__file__).resolve().parents[1] / 'config'
#: The design before the search (issue 26): the truth plants' bench keeps it.
OLD_DESIGN = Path(__file__).resolve().parents[2] / 'test' / 'bench_rig'


@pytest.mark.parametrize('joint', ['hip', 'knee'])
def test_the_margins_and_the_design_checks_walking_speed_agree(joint):
    # Two ways to the walk's peak cylinder speed: the lever arm times the angular rate here,
    # the derivative of the cylinder length over the gait phase in the design-check row.
    params = load_parameters(joint)
    rows = {row.id: row for row in design_check(params)}
    need = {m.id: m for m in design_margins(params)}['walk_speed'].need
    assert need == pytest.approx(rows['walking_speed'].model, rel=5e-3)


def test_a_design_that_misses_a_requirement_is_reported_with_what_it_misses(tmp_path, capsys):
    # A pump a fifth as large: the file's knee walks at 0.85 strides/s even less.
    text = (CONFIG / 'knee.yaml').read_text()
    small = tmp_path / 'small_pump.yaml'
    small.write_text(re.sub(r'pump_displacement: .*', 'pump_displacement: 1.2732e-08', text))
    assert main(['--params', str(small)]) == 0
    out = capsys.readouterr().out
    assert re.search(r'walk_speed .* MISSED', out)
    assert not re.search(r'squat_pressure .* MISSED', out)


def test_the_walking_speed_is_the_time_derivative_of_the_cylinder_length():
    # The need takes the lever arm times the angular rate; here the length is differentiated
    # along Winter's cycle in time instead, on a finer grid.
    params = load_parameters('knee')
    linkage = Linkage.from_parameters(params)
    gait = load_gait_cycle()
    t = np.linspace(0.0, 1.0 / STRIDE_FREQUENCY, 40_001)
    _, knee = gait.angles_at(t * STRIDE_FREQUENCY)
    speed = np.gradient(linkage.cylinder_length(knee), t)
    asked = demand(linkage, motions('knee'))
    assert asked.speed['walk'] == pytest.approx(np.max(np.abs(speed)), rel=5e-3)


def test_the_pump_bounds_the_displacement_per_radian_from_above_and_the_pressure_from_below():
    params = load_parameters('hip')
    linkage = Linkage.from_parameters(params)
    tasks = motions('hip')
    base = {m.id: m for m in margins(Design(0.014, 0.008, linkage), params,
                                     demand(linkage, tasks))}
    # Twice the pivot radii: twice the lever arm along the whole range.
    double = Linkage(2 * linkage.ac, 2 * linkage.co, 2 * linkage.bd, 2 * linkage.od,
                     linkage.angle_offset, 2 * linkage.length_min, 2 * linkage.stroke)
    wide = {m.id: m for m in margins(Design(0.014, 0.008, double), params,
                                     demand(double, tasks))}
    assert wide['walk_speed'].need == pytest.approx(2 * base['walk_speed'].need)
    assert wide['walk_pressure'].need == pytest.approx(base['walk_pressure'].need / 2)
    capacity = SPEED_SHARE * params.pump_displacement * params.motor_speed_max / (
        math.pi / 4 * 0.014 ** 2)
    assert base['walk_speed'].capacity == pytest.approx(capacity)
    # The walking load: Winter's peak extensor moment per kg of the hip (0.6 N m/kg) over
    # the lever arm where it acts, for the design mass.
    gait = load_gait_cycle()
    phase = gait.cycle_percent[np.argmax(gait.hip_moment)] / 100.0
    hip, _ = gait.angles_at(phase)
    at_peak = DESIGN_MASS * np.max(gait.hip_moment) / (linkage.lever_arm(hip) * math.pi / 4
                                                      * 0.014 ** 2)
    assert base['walk_pressure'].need >= at_peak * (1 - 1e-9)


def test_the_squat_moments_are_the_virtual_work_of_the_carried_load():
    # Per leg, the load's height over the ankle in the joint angles (shank lean beta, knee
    # and hip flexion); a joint's moment that holds it is minus its derivative times half
    # the weight, the ankle's zero where the posture balances.
    def height(beta, knee, hip):
        return (SHANK_LENGTH * np.cos(beta) + THIGH_LENGTH * np.cos(knee - beta)
                + LOAD_HEIGHT * np.cos(hip - knee + beta))

    hip, knee, mass = math.radians(35.0), math.radians(60.0), 25.0
    hip_moment, knee_moment = squat_moments(hip, knee, mass)
    # Find the balancing shank lean the slow way: where the ankle's moment vanishes.
    betas = np.linspace(0.0, knee, 200_001)
    h = 1e-6
    ankle = -(height(betas + h, knee, hip) - height(betas - h, knee, hip)) / (2 * h)
    beta = betas[np.argmin(np.abs(ankle))]
    weight = 0.5 * mass * GRAVITY
    expected_knee = -weight * (height(beta, knee + h, hip) - height(beta, knee - h, hip)) / (2 * h)
    expected_hip = -weight * (height(beta, knee, hip + h) - height(beta, knee, hip - h)) / (2 * h)
    assert_allclose([hip_moment, knee_moment], [expected_hip, expected_knee], rtol=1e-3)
    assert knee_moment > hip_moment > 0.0
    assert_allclose(squat_moments(0.0, 0.0, mass), [0.0, 0.0], atol=1e-9)


def test_each_squatting_posture_balances_the_load_over_the_ankle():
    # The shank's lean comes from the knee's moment (the knee's lever arm is l_s sin(beta)),
    # the load's lever arm from the hip's; over the ankle, their sum with the trunk's is 0.
    rng = np.random.default_rng(3)
    knee = rng.uniform(0.05, 2.0, 2000)
    hip = knee * rng.uniform(0.0, 1.0, 2000)
    weight = 0.5 * 10.0 * GRAVITY
    hip_moment, knee_moment = squat_moments(hip, knee, 10.0)
    beta = np.arcsin(knee_moment / weight / SHANK_LENGTH)
    load_x = -hip_moment / weight + LOAD_HEIGHT * np.sin(hip - knee + beta)
    assert_allclose(load_x, 0.0, atol=1e-12)
    assert np.all(knee_moment > 0.0)


@pytest.fixture(scope='module')
def shipped_search():
    """Run the full search on the shipped files' joints once for the module (12 s here)."""
    joints = [load_parameters('hip'), load_parameters('knee')]
    return joints, search(joints)


@pytest.mark.slow
def test_the_shipped_files_carry_the_searched_design_which_beats_the_old_one(shipped_search):
    joints, choices = shipped_search
    assert {c.design.bore for c in choices.values()} == {choices['hip'].design.bore}
    for params in joints:
        choice = choices[params.joint_type]
        assert all(m.met for m in choice.margins if m.kind in ('limit', 'requirement'))
        # The files hold the search's design, rounded to 0.1 mm and 0.1 mrad.
        design = choice.design
        linkage = design.linkage
        assert_allclose([params.bore_diameter, params.rod_diameter, params.stroke],
                        [design.bore, design.rod, linkage.stroke], atol=1e-9)
        assert_allclose([params.link_ac, params.link_co, params.link_bd, params.link_od,
                         params.cylinder_length_min],
                        [linkage.ac, linkage.co, linkage.bd, linkage.od, linkage.length_min],
                        atol=1e-4)
        assert params.angle_offset == pytest.approx(linkage.angle_offset, abs=1e-4)
        # So the file's own check meets what it claims: a file edited into a design that
        # misses a requirement or a limit fails here.
        shipped = design_margins(params)
        assert all(m.met for m in shipped if m.kind in ('limit', 'requirement')), [
            m for m in shipped if not m.met and m.kind != 'given']
        # The design before the search (issue 26), kept as the truth plants' bench.
        old = design_margins(load_parameters(OLD_DESIGN / f'{params.joint_type}.yaml'))
        assert min(m.ratio for m in shipped if m.kind == 'requirement') > min(
            m.ratio for m in old if m.kind == 'requirement')


def test_requirements_no_design_can_meet_are_reported_missed_not_raised():
    # A pump a tenth as large cannot walk at the paper's cadence under any linkage that holds
    # the load: the search still chooses, and the table says what it misses.
    small = load_parameters('knee').replace(pump_displacement=6.4e-9)
    choice = search([small], grid=8)['knee']
    missed = [m for m in choice.margins if not m.met]
    assert {m.id for m in missed} & {'walk_speed', 'walk_pressure', 'squat_pressure'}
    assert all(m.kind == 'requirement' for m in missed)  # every limit still met


@pytest.mark.slow
def test_the_command_prints_the_margins_and_writes_the_feasible_region(tmp_path, capsys,
                                                                     monkeypatch,
                                                                     shipped_search):
    joints, choices = shipped_search

    def searched(given):
        # The command searches the same two shipped joints: the module's search stands in.
        assert given == joints
        return choices

    monkeypatch.setattr('exo_has_sim.design_check.search', searched)
    plot = tmp_path / 'region.png'
    assert main(['--joint', 'knee', '--search', '--plot', str(plot)]) == 0
    out = capsys.readouterr().out
    assert 'walk_speed' in out and 'squat_pressure' in out
    assert 'where the searched designs depart from the paper' in out
    assert re.search(r"walking stroke [\d.]+ mm against the paper's 58 mm", out)
    assert plot.stat().st_size > 10_000
