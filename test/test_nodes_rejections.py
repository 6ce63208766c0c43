"""nodes/rejections.RejectionLog without ROS: per reason, the first at once, then at most one
line per period with the count and the latest; a flush on time; the totals at close."""
from supersafe_ros.nodes.rejections import RejectionLog


def test_each_reason_is_told_at_once_then_counted_once_a_period_and_totalled():
    lines = []
    log = RejectionLog('intervention', 'rejected', lines.append, period=1.0)
    for k in range(100):
        log.add('invalid stamp', f'stamp {k}', 10.0 + 0.001 * k)
        log.add('duplicate', f'dup {k}', 10.0 + 0.001 * k)
    assert lines == ['intervention rejected (invalid stamp): stamp 0', 'intervention rejected (duplicate): dup 0']
    assert log.flush(10.5) == 0                   # the period is not over
    assert log.flush(11.0) == 2                   # over: the counts come without another message
    assert lines[2] == '99 more interventions rejected (invalid stamp) in the last 1 s; latest: stamp 99'
    assert log.flush(11.5) == 0 and log.flush(12.0) == 0         # nothing more came: quiet, window closed
    log.add('duplicate', 'dup again', 12.1)
    assert lines[-1] == 'intervention rejected (duplicate): dup again'     # a new burst: told at once
    log.add('duplicate', 'dup twice', 12.2)
    log.close(12.3)                               # shutdown: what is pending, then the totals
    assert lines[-2] == '1 more intervention rejected (duplicate) in the last 1 s; latest: dup twice'
    assert lines[-1] == 'interventions rejected this run: 202 (duplicate 102, invalid stamp 100)'
    assert log.total == 202 and log.latest == 'duplicate: dup twice'


def test_nothing_is_said_at_close_when_nothing_was_rejected():
    lines = []
    RejectionLog('intervention', 'rejected', lines.append).close(0.0)
    assert lines == []
