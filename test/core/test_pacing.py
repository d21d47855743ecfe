"""Pacing policies of block producers."""

from emfc_ros.core.pacing import ClockPacer, ConsumerPacer


def test_clock_pacer_allows_blocks_as_time_passes_with_lead():
    p = ClockPacer(sample_rate_Hz=1000.0, block_size=100, lead_blocks=2, start_time_s=5.0)
    assert p.allowed_index(5.0) == 300          # block 0 due now, plus 2 ahead
    assert p.allowed_index(5.0999) == 300
    assert p.allowed_index(5.1) == 400
    assert p.allowed_index(4.0) == 0            # before the start nothing is due
    assert abs(p.lag_s(5.5, 300, 1000.0) - 0.2) < 1e-12


def test_consumer_pacer_window_and_stale_acknowledgements():
    p = ConsumerPacer(block_size=100, window_blocks=4)
    assert p.allowed_index() == 400
    p.acknowledge(250)
    assert p.allowed_index() == 650
    p.acknowledge(100)                          # stale: ignored
    assert p.allowed_index() == 650
    p.reset()
    assert p.allowed_index() == 400
