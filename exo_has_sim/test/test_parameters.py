import dataclasses

import pytest

from exo_has_sim.errors import ParameterError
from exo_has_sim.parameters import CONFIG_DIR, HasParameters, load_parameters


@pytest.mark.parametrize('joint', ['hip', 'knee'])
def test_every_value_of_both_sets_has_its_provenance(joint):
    params = load_parameters(joint)
    names = [f.name for f in dataclasses.fields(HasParameters)
             if f.name not in ('joint_type', 'effects', 'provenance', 'uncertainty')]
    missing = [name for name in names if not params.provenance.get(name, '').strip()]
    assert missing == []
    for name in names:
        text = params.provenance[name]
        assert text.startswith(('paper', 'assumed', 'no paper value', 'design search')), (
            name, text)


def test_the_paper_values_are_carried_over_in_si_units():
    params = load_parameters('hip')
    assert params.pump_displacement * 2 * 3.141592653589793 == pytest.approx(0.4e-6)
    assert params.motor_speed_max == pytest.approx(4000 * 2 * 3.141592653589793 / 60)
    assert params.max_working_pressure == 18e6 and params.peak_thrust == 1770.0
    assert params.load_mass == 50.0 and params.control_rate == 200.0
    assert params.effects.enabled == []


@pytest.mark.parametrize(('name', 'value', 'message'), [
    ('bore_diameter', 14, r'bore_diameter = 14 is outside \[0.004, 0.2\] m'),
    ('motor_speed_max', 4000, r'motor_speed_max = 4000 is outside .* rad/s \(4000 r/min'),
    ('relief_pressure', 180.0, 'relief_pressure = 180.0 is outside'),
    ('pump_displacement', 0.4, 'pump_displacement = 0.4 is outside'),
    ('damping', 'high', 'damping must be a number'),
])
def test_values_in_wrong_units_or_types_fail_naming_the_value(tmp_path, name, value, message):
    text = (CONFIG_DIR / 'hip.yaml').read_text()
    lines = [f'      {name}: {value}' if line.startswith(f'      {name}: ') and
             "'" not in line else line for line in text.splitlines()]
    path = tmp_path / 'bad.yaml'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(ParameterError, match=message):
        load_parameters(path)


def test_missing_and_unknown_values_and_effects_are_named(tmp_path):
    text = (CONFIG_DIR / 'hip.yaml').read_text()
    path = tmp_path / 'p.yaml'
    path.write_text(text.replace('      damping: 1500.0\n', '      dampin: 1500.0\n'))
    with pytest.raises(ParameterError, match='missing damping'):
        load_parameters(path)
    path.write_text(text.replace('      damping: 1500.0\n',
                                 '      damping: 1500.0\n      effects: {colomb_friction: 5.0}\n'))
    with pytest.raises(ParameterError, match='unknown effect colomb_friction'):
        load_parameters(path)
    path.write_text('has: {}\n')
    with pytest.raises(ParameterError, match='expected /\\*\\*: ros__parameters: has'):
        load_parameters(path)


def test_effects_and_relations_are_checked():
    params = load_parameters('hip')
    with pytest.raises(ParameterError, match='relief_crack_pressure must lie below'):
        params.replace(effects=dataclasses.replace(params.effects,
                                                   relief_crack_pressure=20e6))
    with pytest.raises(ParameterError, match='rod_diameter must be smaller'):
        params.replace(rod_diameter=0.02)
    assert params.with_effects(coulomb_friction=50.0).effects.enabled == ['coulomb_friction']


def test_the_parameter_files_are_ros2_params_files_that_rcl_reads():
    from rclpy.context import Context
    from rclpy.node import Node

    context = Context()
    context.init(['test', '--ros-args', '--params-file', str(CONFIG_DIR / 'hip.yaml')])
    try:
        node = Node('any_node', context=context,
                    automatically_declare_parameters_from_overrides=True)
        hip = load_parameters('hip')
        assert node.get_parameter('has.bore_diameter').value == hip.bore_diameter
        assert node.get_parameter('has.bulk_modulus').value == hip.bulk_modulus
        assert node.get_parameter('provenance.bore_diameter').value == \
            hip.provenance['bore_diameter']
        node.destroy_node()
    finally:
        context.try_shutdown()


def test_the_stated_uncertainties_are_read_and_a_bad_one_is_named(tmp_path):
    params = load_parameters('hip')
    assert params.uncertainty == {'motor_time_constant': 0.3, 'pump_displacement': 0.15,
                                  'dead_volume': 0.3}
    text = (CONFIG_DIR / 'hip.yaml').read_text()
    path = tmp_path / 'p.yaml'
    for stated, message in (('dead_volume: 30', r'uncertainty.dead_volume must be a relative'),
                            ('dead_volume: -0.1', r'uncertainty.dead_volume must be a relative'),
                            ("dead_volume: 'wide'", r'uncertainty.dead_volume must be'),
                            ('dead_volum: 0.3',
                             "uncertainty of an unknown parameter 'dead_volum'")):
        path.write_text(text.replace('      dead_volume: 0.3\n', f'      {stated}\n'))
        with pytest.raises(ParameterError, match=message):
            load_parameters(path)
    path.write_text(text.replace('    uncertainty:\n', '    uncertainty: 0.3\n    ignored:\n'))
    with pytest.raises(ParameterError, match='uncertainty must be a mapping'):
        load_parameters(path)
