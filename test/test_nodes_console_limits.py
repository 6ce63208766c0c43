"""supervisor_console_node's bounds on unfinished HTTP requests are parameters (issue 29):
declared with descriptors, in config/console.yaml, and in force in the node's server
(slow connections to the node's own port are closed: over the cap at once, the rest
after the header timeout)."""
import asyncio
from pathlib import Path

import pytest
import yaml
from rclpy.parameter import Parameter

from supersafe_ros.nodes.supervisor_console_node import SupervisorConsoleNode
from console_support import closed_by_server

pytestmark = pytest.mark.ros   # rclpy nodes in this process

REPO = Path(__file__).resolve().parents[1]


def test_the_unfinished_request_bounds_are_parameters_in_force(ros_context):
    (declared,) = yaml.safe_load((REPO / 'config' / 'console.yaml').read_text()).values()
    params = declared['ros__parameters']
    assert params['header_timeout'] == 10.0 and params['max_unfinished'] == 64
    node = SupervisorConsoleNode(context=ros_context, parameter_overrides=[
        Parameter('port', value=0), Parameter('header_timeout', value=0.5), Parameter('max_unfinished', value=3)])
    try:
        for name, (lo, hi) in (('header_timeout', (0.1, 600.0)), ('max_unfinished', (1, 10000))):
            (d,) = node.describe_parameters([name])
            r = (d.floating_point_range or d.integer_range)[0]
            assert d.description and d.read_only and (r.from_value, r.to_value) == (lo, hi)
        server = node.server
        assert server.header_timeout == 0.5 and server.unfinished.cap == 3

        async def run():
            conns = []
            for _ in range(10):
                reader, writer = await asyncio.open_connection('127.0.0.1', server.port)
                writer.write(b'GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n')
                conns.append((reader, writer))
            closed = [await closed_by_server(reader) for reader, _ in conns]
            for _, writer in conns:
                writer.close()
            return closed
        assert all(asyncio.run(run()))
        assert server.unfinished.evicted == 7 and server.unfinished.abandoned == 10
    finally:
        node.close()
        node.destroy_node()
