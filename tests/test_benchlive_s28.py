"""``bench_realtime`` runs in a tiny setting: its relay trial over real sockets, a phone process and the
recorder logs every packet. (``bench_speak`` needs a trained run: a fit of over 20 s, left to the bench.)"""

from __future__ import annotations


def test_relay_trial_records_every_packet():
    from benchmarks.bench_realtime import relay_trial

    got, rate, cpu = relay_trial(240, 1, 240.0)
    assert got == 240
    assert rate > 0 and cpu > 0
