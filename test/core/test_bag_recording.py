"""
The queued writer thread: counting, periodic flushes that survive a kill, write errors.

The full disk is a file size limit (RLIMIT_FSIZE) in a child process: no root needed.
"""

import json
from pathlib import Path
import shutil
import subprocess
import sys
import textwrap
import time

import numpy as np
from rosbags.typesys import get_typestore, Stores

from emfc_ros.core.bag import (
    BagWriter, OfferedQos, QueuedBagWriter, read_metadata, read_streams, repair_bag)
from emfc_ros.core.blocks import pack
from ros_harness import scaled

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
REPO = Path(__file__).resolve().parents[2]


def block_cdr(first, n):
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    x = np.vstack([np.arange(first, first + n, dtype=float)])
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[dim('channel', 1, n), dim('sample', n, n)],
                                                data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, 1000.0, 1, x)), F64)


def wait_for(predicate, timeout_s=scaled(10.0)):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_counts_custom_data_and_a_proper_close(tmp_path):
    queued = QueuedBagWriter(BagWriter(tmp_path / 'b'), flush_period_s=0.05)
    queued.start()
    cid = queued.add_connection('/s', F64, [OfferedQos()])
    queued.set_custom_data('emfc_ros.version', '1.2')
    for i in range(100):
        assert queued.put(cid, 10 + i, block_cdr(100 * i, 100))
    stats = queued.stop()
    assert stats.state == 'closed' and stats.error == '' and stats.dropped == 0
    assert stats.messages == {'/s': 100} and stats.total_messages == 100
    assert stats.total_bytes == 100 * len(block_cdr(0, 100))
    assert stats.files == ['b_0.mcap'] and stats.queue_depth == 0
    assert not queued.running
    assert not queued.put(cid, 1, b'late')
    assert queued.stats().dropped == 1
    assert read_metadata(tmp_path / 'b')['custom_data'] == {'emfc_ros.version': '1.2'}
    assert read_streams(tmp_path / 'b')['/s'].n_samples == 10000


class GatedWriter(BagWriter):
    """A bag writer whose message writes wait for the test (the writer thread mid-write)."""

    def __init__(self, path):
        super().__init__(path)
        import threading
        self.inside = threading.Event()
        self.go_on = threading.Event()

    def write(self, *args, **kwargs):
        self.inside.set()
        assert self.go_on.wait(scaled(10.0))
        return super().write(*args, **kwargs)


def test_a_message_being_written_is_still_queued_so_an_empty_queue_means_all_counted(tmp_path):
    # The runner's accounting reads the counts once the queue is empty; a message the
    # writer thread had taken but not yet counted made a bag hold one /diagnostics message
    # more than its counts said (CI). It leaves the queue as it is counted.
    writer = GatedWriter(tmp_path / 'b')
    queued = QueuedBagWriter(writer, flush_period_s=10.0)
    queued.start()
    cid = queued.add_connection('/diagnostics', F64)
    assert queued.put(cid, 1, block_cdr(0, 10))
    assert writer.inside.wait(scaled(10.0))          # taken from the queue, being written
    stats = queued.stats()
    assert (stats.queue_depth, stats.messages) == (1, {'/diagnostics': 0})
    writer.go_on.set()
    assert wait_for(lambda: queued.stats().queue_depth == 0)
    assert queued.stats().messages == {'/diagnostics': 1}
    assert queued.stop().messages == {'/diagnostics': 1}


def test_queue_bounds_drop_and_count_instead_of_growing(tmp_path):
    queued = QueuedBagWriter(BagWriter(tmp_path / 'b'), max_queue_messages=10,
                             max_queue_B=len(block_cdr(0, 100)) + 10)
    queued.start()
    cid = queued.add_connection('/s', F64)
    assert not queued.put(cid, 1, block_cdr(0, 200))  # larger than the byte bound
    assert queued.put(cid, 2, block_cdr(0, 100))
    stats = queued.stop()
    assert stats.dropped == 1 and stats.messages == {'/s': 1} and stats.queue_depth == 0
    assert 1 <= stats.queue_high_water <= 10


def test_periodic_flush_puts_data_on_disk_before_any_close(tmp_path):
    queued = QueuedBagWriter(BagWriter(tmp_path / 'b'), flush_period_s=0.1)
    queued.start()
    cid = queued.add_connection('/s', F64)
    queued.set_custom_data('k', 'v')
    for i in range(50):
        queued.put(cid, 10 + i, block_cdr(100 * i, 100))
    size = len(block_cdr(0, 100))
    assert wait_for(lambda: queued.stats().flushes >= 1
                    and (tmp_path / 'b' / 'b_0.mcap').stat().st_size > 50 * size)
    # What is on disk now is what a killed process would leave behind.
    shutil.copytree(tmp_path / 'b', tmp_path / 'snapshot')
    queued.stop()
    report = repair_bag(tmp_path / 'snapshot')
    assert report.message_count == 50
    assert read_metadata(tmp_path / 'snapshot')['custom_data'] == {'k': 'v'}
    assert read_streams(tmp_path / 'snapshot')['/s'].n_samples == 5000


FULL_DISK_SCRIPT = textwrap.dedent("""
    import json, resource, signal, sys
    resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    import time
    sys.path[:0] = [{test_dir!r}, {test_root!r}]
    from test_bag_recording import block_cdr, wait_for
    from emfc_ros.core.bag import BagWriter, QueuedBagWriter
    queued = QueuedBagWriter(BagWriter(sys.argv[1], chunk_size_B=20_000), flush_period_s=0.05)
    queued.start()
    cid = queued.add_connection('/s', 'std_msgs/msg/Float64MultiArray')
    for i in range(20):  # 160 kB, then a flush
        queued.put(cid, 10 + i, block_cdr(1000 * i, 1000))
    wait_for(lambda: queued.stats().flushes >= 1 and queued.stats().total_messages == 20)
    for i in range(20, 100):  # 640 kB more: beyond the file size limit
        queued.put(cid, 10 + i, block_cdr(1000 * i, 1000))
    wait_for(lambda: queued.stats().state == 'error')
    stats = queued.stop()
    print(json.dumps({{'state': stats.state, 'error': stats.error,
                       'messages': stats.total_messages, 'dropped': stats.dropped}}))
""")


def test_full_disk_is_an_error_and_the_flushed_data_survive(tmp_path):
    script = FULL_DISK_SCRIPT.format(test_dir=str(Path(__file__).parent),
                                     test_root=str(Path(__file__).parents[1]))
    out = subprocess.run([sys.executable, '-c', script, str(tmp_path / 'b')], cwd=REPO,
                         capture_output=True, text=True, timeout=scaled(60))
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result['state'] == 'error' and 'File too large' in result['error']
    assert 20 <= result['messages'] < 100
    assert result['dropped'] == 100 - result['messages']
    report = repair_bag(tmp_path / 'b')
    s = read_streams(tmp_path / 'b')['/s']
    assert s.first_sample_index == 0 and s.gaps == [] and s.n_samples >= 20_000
    assert report.message_count == s.n_samples // 1000
    np.testing.assert_array_equal(s.samples[0], np.arange(s.n_samples, dtype=float))
