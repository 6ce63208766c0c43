"""The filter node's parameter table against FilterConfig and the shipped config files.

Each default has one source: FilterConfig's field defaults for its fields, the table
(filter_parameters.PARAMETERS, the one node's: safety_filter_node and fleet_safety_filter_node
alike) for the rest. The YAML files repeat them for the reader; any drift fails here.
"""
from dataclasses import fields
from pathlib import Path

import pytest
import yaml

from supersafe_ros.filter import FilterConfig
from supersafe_ros.nodes.filter_parameters import (CONFIG_PARAMETERS, FILTER_PARAMETERS, PARAMETERS,
                                                   check_config_field, decision_mode, robot_namespaces)

CONFIG = Path(__file__).resolve().parents[1] / 'config'
RCLPY_DEFAULTS = {'use_sim_time': False}     # declared by rclpy itself

NODES = {'safety_filter.yaml': PARAMETERS, 'fleet_safety_filter.yaml': PARAMETERS}
# values a config file sets on purpose, not as the node's default (each with its reason)
DEPLOYMENT_VALUES = {
    'fleet_safety_filter.yaml': {
        'robots': ['robot_0', 'robot_1'],    # an example fleet; the node alone serves its own namespace
        'batched_topics': True,              # a fleet manager's one message a tick
        'state_rate': 2.0,                   # per robot: a fleet sends fewer periodic states
        'level_set_markers': False,          # a publisher per robot (RViz): not for a fleet
    },
}
LIVE = {
    'safety_filter.yaml': {'standard_alpha', 'alpha_offset', 'use_learned', 'pose_timeout', 'detections_timeout',
                           'hold_timeout', 'cmd_timeout', 'clear_margin', 'lookahead', 'control_period', 'rate',
                           'state_rate', 'max_value_function_bytes', 'clock_stall_timeout', 'publish_on_pose',
                           'max_detections', 'stamp_tolerance', 'time_before_collision'},
}
LIVE['fleet_safety_filter.yaml'] = LIVE['safety_filter.yaml']


def config_values(name):
    (section,) = yaml.safe_load((CONFIG / name).read_text()).values()
    return section['ros__parameters']


@pytest.mark.parametrize('name', sorted(NODES))
def test_every_value_in_the_config_file_is_the_nodes_default(name):
    defaults = {**RCLPY_DEFAULTS, **{p.name: p.default for p in NODES[name]}}
    deliberate = DEPLOYMENT_VALUES.get(name, {})
    values = config_values(name)
    assert set(values) == set(defaults), 'the file lists every parameter of the node, and only those'
    for key, value in values.items():
        expected = deliberate.get(key, defaults[key])
        assert value == expected and type(value) is type(expected), (key, value, expected)
    for key, value in deliberate.items():
        assert value != defaults[key], f'{key}: the default now; drop it from DEPLOYMENT_VALUES'


def test_filter_config_fields_take_their_defaults_from_filter_config():
    config_defaults = {f.name: f.default for f in fields(FilterConfig)}
    from_config = [p for p in FILTER_PARAMETERS if p.name in config_defaults]
    assert {p.name for p in from_config} == {'speed', 'omega_max', 'radius', 'fail_safe_command',
                                             *(p.name for p in CONFIG_PARAMETERS)}
    for p in from_config:
        # a count: an integer parameter; a choice: a string
        kind = {'max_detections': int, 'fail_safe_command': str}.get(p.name, float)
        assert p.default == config_defaults[p.name] and type(p.default) is kind, p.name


@pytest.mark.parametrize('name', sorted(NODES))
def test_every_parameter_has_a_description_and_numbers_a_range_holding_the_default(name):
    specs = NODES[name]
    assert len({p.name for p in specs}) == len(specs), 'a parameter declared twice'
    for p in specs:
        assert p.description.strip(), p.name
        if isinstance(p.default, (int, float)) and not isinstance(p.default, bool):
            assert p.lo is not None and p.hi is not None and p.lo <= p.default <= p.hi, p.name
    assert {p.name for p in specs if p.live} == LIVE[name]


def test_a_config_value_is_checked_against_filter_config_before_it_is_applied():
    config = FilterConfig()
    assert check_config_field(config, 'pose_timeout', 0.05) is None
    assert 'pose_timeout must be finite and >= 0' in check_config_field(config, 'pose_timeout', float('nan'))
    assert check_config_field(config, 'lookahead', -1.0)
    assert config == FilterConfig()        # nothing applied


def test_robots_resolve_as_topic_names_do_and_name_each_namespace_once():
    assert robot_namespaces('/', ['']) == ['/']
    assert robot_namespaces('/robot_0', ['']) == ['/robot_0']
    assert robot_namespaces('/', ['robot_0', '/fleet/r1/']) == ['/robot_0', '/fleet/r1']
    assert robot_namespaces('/site', ['robot_0', '/robot_1']) == ['/site/robot_0', '/robot_1']
    with pytest.raises(ValueError, match='twice'):
        robot_namespaces('/', ['robot_0', '/robot_0'])
    with pytest.raises(ValueError, match='empty'):
        robot_namespaces('/', [])


def test_a_robot_on_its_own_topics_is_decided_on_its_inputs_a_fleet_on_ticks():
    assert decision_mode('auto', 1, True, False) == 'input'
    assert decision_mode('auto', 2, True, False) == 'tick'
    assert decision_mode('auto', 1, True, True) == 'tick'       # a fleet/poses message is a tick
    assert decision_mode('tick', 1, True, False) == 'tick'
    assert decision_mode('input', 60, True, False) == 'input'
    with pytest.raises(ValueError, match='batched_topics'):
        decision_mode('input', 1, True, True)
    with pytest.raises(ValueError, match='one of'):
        decision_mode('sometimes', 1, True, False)
