"""fleet_safety_filter_node: safety_filter_node for a whole fleet, under the name fleet_safety_filter.

The same node (``safety_filter_node.SafetyFilter``, the same parameters, topics and decision),
run with config/fleet_safety_filter.yaml: ``robots`` names every robot's namespace (each its own
topics, as a lone filter's), ``batched_topics`` adds fleet/poses -> fleet/cmd_vel for a fleet
manager or simulator that holds every robot's state, and ``decide_on`` (auto: tick for more than
one robot) decides every robot at once, ``rate`` times a second. docs/fleet.md.
"""
from __future__ import annotations

from .common import run_node
from .safety_filter_node import ManagedSafetyFilterNode, SafetyFilterNode


class FleetSafetyFilterNode(SafetyFilterNode):
    """safety_filter_node named fleet_safety_filter."""

    def __init__(self, node_name='fleet_safety_filter', **kwargs):
        super().__init__(node_name, **kwargs)


class ManagedFleetSafetyFilterNode(ManagedSafetyFilterNode):
    """managed_safety_filter named fleet_safety_filter."""

    def __init__(self, node_name='fleet_safety_filter', **kwargs):
        super().__init__(node_name, **kwargs)


def main(args=None):
    return run_node(FleetSafetyFilterNode, args)


def main_managed(args=None):
    return run_node(ManagedFleetSafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
