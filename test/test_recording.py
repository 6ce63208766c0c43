"""Recording to rosbag2 bags (MCAP storage): the ROS-free writer, message definitions, and
the graph recorder at topic level (the test publishes, the recorder records, the bag is
read back with the mcap reader + mcap_ros2 decoder and with rosbags' rosbag2 reader)."""
import time

import pytest
import yaml
from rclpy.serialization import serialize_message

from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from supersafe_ros.nodes.markers import obstacles_to_markers
from supersafe_ros.recording.bag import BagWriter, DefinitionNotFound, qos_profile, typestore
from supersafe_ros.ros_io import rosmsg

from bag_support import read_bag
from graph_support import Spinner, matched


# -- message definitions ---------------------------------------------------------------------------
def test_types_come_from_the_jazzy_typestore_and_unknown_ones_are_refused(tmp_path):
    with BagWriter(tmp_path / 'b') as bag:
        with pytest.raises(DefinitionNotFound):
            bag.add_topic('/x', 'no_such_msgs/msg/Nothing')
        with pytest.raises(DefinitionNotFound):     # another version of the type: not decodable
            bag.add_topic('/y', 'geometry_msgs/msg/PoseStamped', type_hash='RIHS01_' + '0' * 64)
        assert not bag.topics
    assert typestore().hash_rihs01('geometry_msgs/msg/PoseStamped').startswith('RIHS01_')


# -- the ROS-free writer ---------------------------------------------------------------------------
def test_bag_round_trip_with_rosbag2_fields(tmp_path):
    bag_dir = tmp_path / 'run1'
    latched = qos_profile(depth=1, durability='transient_local')
    with BagWriter(bag_dir) as bag:
        bag.add_topic('/interventions', 'geometry_msgs/msg/PoseStamped', [qos_profile(depth=100)])
        bag.add_topic('/obstacle_markers', 'visualization_msgs/msg/MarkerArray', [latched])
        markers = obstacles_to_markers([3, 7], [(1.0, 2.0), (-4.0, 0.5)], 1.8)
        bag.write('/obstacle_markers', serialize_message(markers), 1_000_000_000)
        for i in range(3):
            msg = rosmsg.state_to_pose((0.5 * i, -2.0, 0.25), None, rosmsg.obstacle_frame(7))
            bag.write('/interventions', serialize_message(msg), 2_000_000_000 + i)
    assert sorted(p.name for p in bag_dir.iterdir()) == ['metadata.yaml', 'run1.mcap']

    header, summary, records, messages = read_bag(bag_dir / 'run1.mcap')
    assert header.profile == 'ros2'
    schemas = {s.name: s for s in summary.schemas.values()}
    assert set(schemas) == {'geometry_msgs/msg/PoseStamped', 'visualization_msgs/msg/MarkerArray'}
    assert all(s.encoding == 'ros2msg' for s in schemas.values())
    assert schemas['geometry_msgs/msg/PoseStamped'].data.decode() == typestore().generate_msgdef(
        'geometry_msgs/msg/PoseStamped', ros_version=2)[0]
    channels = {c.topic: c for c in summary.channels.values()}
    assert all(c.message_encoding == 'cdr' for c in channels.values())
    qos = yaml.safe_load(channels['/obstacle_markers'].metadata['offered_qos_profiles'])
    assert qos == [latched] and qos[0]['durability'] == 'transient_local'
    assert summary.statistics.message_count == 4

    # the record rosbag2's MCAP plugin reads its metadata from: BagMetadata, version 9
    inner = yaml.safe_load(records['rosbag2']['serialized_metadata'])
    on_disk = yaml.safe_load((bag_dir / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert inner == on_disk
    assert on_disk['version'] == 9 and on_disk['storage_identifier'] == 'mcap'
    assert on_disk['relative_file_paths'] == ['run1.mcap'] and on_disk['message_count'] == 4
    counts = {t['topic_metadata']['name']: t['message_count'] for t in on_disk['topics_with_message_count']}
    assert counts == {'/interventions': 3, '/obstacle_markers': 1}
    assert all(t['topic_metadata']['type_description_hash'].startswith('RIHS01_')
               for t in on_disk['topics_with_message_count'])
    assert on_disk['starting_time']['nanoseconds_since_epoch'] == 1_000_000_000
    assert on_disk['duration']['nanoseconds'] == 1_000_000_002

    got = [(d.header.frame_id, d.pose.position.x, t)
           for topic, _, _, d, t in messages if topic == '/interventions']
    assert got == [('obstacle_7', 0.0, 2_000_000_000), ('obstacle_7', 0.5, 2_000_000_001),
                   ('obstacle_7', 1.0, 2_000_000_002)]
    decoded_markers = next(d for topic, _, _, d, _ in messages if topic == '/obstacle_markers')
    assert [m.id for m in decoded_markers.markers[1:]] == [3, 7]

    with pytest.raises(FileExistsError):      # a bag is never overwritten
        BagWriter(bag_dir)


def test_bag_reads_back_through_an_independent_rosbag2_reader(tmp_path):
    """rosbags (a pure-Python rosbag2 implementation) opens the folder as ros2 bag does:
    metadata.yaml, storage mcap, QoS, and the ros2msg definitions (it parses them itself)."""
    rosbag2 = pytest.importorskip('rosbags.rosbag2')
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/interventions', 'geometry_msgs/msg/PoseStamped',
                      [qos_profile(depth=100, reliability='reliable')])
        msg = rosmsg.state_to_pose((1.25, -0.5, 0.0), None, rosmsg.obstacle_frame(4))
        bag.write('/interventions', serialize_message(msg), 5_000_000_000)
    store = get_typestore(Stores.EMPTY)
    with rosbag2.Reader(tmp_path / 'b') as reader:
        (conn,) = reader.connections
        assert (conn.topic, conn.msgtype, conn.ext.serialization_format) == (
            '/interventions', 'geometry_msgs/msg/PoseStamped', 'cdr')
        assert conn.ext.offered_qos_profiles[0].depth == 100
        store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        (_, t, raw), = list(reader.messages())
        decoded = store.deserialize_cdr(raw, conn.msgtype)
    assert t == 5_000_000_000
    assert decoded.header.frame_id == 'obstacle_4' and decoded.pose.position.x == 1.25


# -- the graph recorder ----------------------------------------------------------------------------
@pytest.mark.ros
def test_recorder_records_latched_and_event_topics_and_finds_interventions(ros_context, tmp_path):
    from supersafe_ros.ros_io.bag_recorder import start_recorder
    import rclpy
    node = rclpy.create_node('recording_test', context=ros_context)
    spin = Spinner(ros_context, node)
    markers_pub = node.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
    interventions_pub = node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
    # published before the recorder exists: it must still get it (transient local)
    markers_pub.publish(obstacles_to_markers([0, 5], [(2.0, 1.0), (-3.0, 4.0)], 1.8))
    rec = start_recorder(tmp_path / 'graph_bag')
    try:
        assert rec.wait_until_recording(['/obstacle_markers', '/interventions'], timeout=30.0), rec.skipped
        spin.until(lambda: matched(interventions_pub), 30.0, 'the recorder subscribed to /interventions')
        sent = [((1.0 + i, -0.5, 0.1 * i), rosmsg.obstacle_frame(5 - 5 * (i % 2))) for i in range(5)]
        for state, frame in sent:
            interventions_pub.publish(rosmsg.state_to_pose(state, None, frame))
        deadline = time.monotonic() + 30.0
        while rec.message_count('/interventions') < len(sent) and time.monotonic() < deadline:
            spin.spin_for(0.02)
        assert rec.message_count('/interventions') == len(sent)
        assert rec.message_count('/obstacle_markers') >= 1
    finally:
        info = rec.stop()
        spin.shutdown()
        node.destroy_node()
    assert info.topics['/interventions'] == len(sent)

    _, summary, _, messages = read_bag(info.mcap_path)
    got = [(d.header.frame_id, round(d.pose.position.x, 9),
            round(rosmsg.quaternion_to_yaw(d.pose.orientation), 9))
           for topic, _, _, d, _ in messages if topic == '/interventions']
    assert got == [(frame, s[0], round(s[2], 9)) for s, frame in sent]
    markers = [d for topic, _, _, d, _ in messages if topic == '/obstacle_markers']
    assert [m.id for m in markers[0].markers[1:]] == [0, 5]
    channels = {c.topic: c for c in summary.channels.values()}
    offered = yaml.safe_load(channels['/obstacle_markers'].metadata['offered_qos_profiles'])
    assert offered and all(q['durability'] == 'transient_local' for q in offered)
    meta = yaml.safe_load((info.path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count'] for t in meta['topics_with_message_count']}
    assert counts['/interventions'] == len(sent)


# -- supersafe team --record -------------------------------------------------------------------------
@pytest.mark.ros
def test_team_run_records_every_topic_and_the_interventions_the_world_logged(tmp_path):
    """A short real team (processes, simulated supervisor) with run_team(record=...): the
    bag has every step's pose and exactly the interventions the world accepted."""
    import os
    from supersafe_ros.team import run_team, team_processes
    fast = {'supervisor': {'grid_nxy': 33, 'grid_ntheta': 16, 'mu': 1.0},
            'safety_filter': {'standard_shape': [33, 33, 16]}}
    duration, step = 12.0, 0.1
    argvs = team_processes(n_robots=1, rate_factor=0.0, seed=3, duration=duration, step=step,
                           with_learner=False, overrides=fast)
    # generous wall deadline: about 15 s on a quiet machine, far more when it is overloaded
    result = run_team(argvs, duration=duration, timeout=240.0, log_dir=tmp_path / 'logs',
                      print_period=1e9, out=open(os.devnull, 'w'), record=tmp_path / 'team_bag')
    clock_log = (tmp_path / 'logs' / 'sim_clock.log').read_text()
    assert result['reason'] == 'duration reached', (result['reason'], clock_log[-2000:])
    assert 'still missing' not in clock_log, clock_log[-2000:]     # it waited for the recorder
    info = result['bag']
    assert info.path == tmp_path / 'team_bag' and (info.path / 'metadata.yaml').is_file()
    assert {'/clock', '/robot_0/pose', '/robot_0/cmd_vel', '/obstacle_markers', '/world/stats',
            '/interventions', '/world/intervention_log'} <= set(info.topics)
    _, _, _, messages = read_bag(info.mcap_path)
    # every step's pose: no step missing between the first and the last; the pose of the
    # final step races the recorder's stop (the run ends when the clock reaches it)
    stamps = sorted(d.header.stamp.sec + d.header.stamp.nanosec * 1e-9
                    for topic, _, _, d, _ in messages if topic == '/robot_0/pose')
    assert info.topics['/robot_0/pose'] == len(stamps) >= round(duration / step) - 1, info.topics
    assert stamps[0] <= step + 1e-6 and stamps[-1] >= duration - step - 1e-6, (stamps[0], stamps[-1])
    gaps = [round(b - a, 6) for a, b in zip(stamps, stamps[1:])]
    assert set(gaps) == {step}, sorted(set(gaps))
    recorded = [int(d.header.frame_id.removeprefix('obstacle_'))
                for topic, _, _, d, _ in messages if topic == '/interventions']
    logged = [int(v['obstacle']) for v in result['interventions']]
    assert recorded and recorded == logged, (recorded, logged)


@pytest.mark.ros
def test_record_command_records_until_ctrl_c(ros_context, tmp_path):
    """`supersafe record BAG` as a process: records what a node publishes, stops cleanly on SIGINT."""
    import os
    import signal
    import subprocess
    import sys
    import rclpy
    from rclpy.duration import Duration
    from std_msgs.msg import String
    node = rclpy.create_node('record_cli_test', context=ros_context)
    pub = node.create_publisher(String, '/chatter', rosmsg.QOS_EVENTS)
    spin = Spinner(ros_context, node)
    proc = subprocess.Popen([sys.executable, '-m', 'supersafe_ros.cli', 'record', str(tmp_path / 'cli_bag')],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED='1'), start_new_session=True)
    try:
        spin.until(lambda: matched(pub), 30.0, 'the recorder to subscribe to /chatter')
        for i in range(20):
            pub.publish(String(data=f'hello {i}'))
        assert pub.wait_for_all_acked(Duration(seconds=30))   # in the recorder's queue
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        spin.shutdown()
        node.destroy_node()
    assert proc.returncode == 0, out
    assert 'recorded' in out and str(tmp_path / 'cli_bag') in out
    _, _, _, messages = read_bag(tmp_path / 'cli_bag' / 'cli_bag.mcap')
    assert [d.data for topic, _, _, d, _ in messages if topic == '/chatter'] == [f'hello {i}' for i in range(20)]
    with pytest.raises(subprocess.CalledProcessError):     # never overwrites
        subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'record', str(tmp_path / 'cli_bag')],
                       check=True, capture_output=True, timeout=60)
