"""The report's reason for a take's look names its offset confidence on the side of the bound it is: 0.4951
under 0.5 read "0.50 < 0.5"."""

from viewer.report import MIN_CONFIDENCE, _outliers


def test_a_confidence_just_under_the_bound_reads_under_it():
    entries = [{"p95": {}, "align": {"offset_confidence": MIN_CONFIDENCE - 0.0049}}]
    _outliers(entries)
    assert entries[0]["reasons"] == ["offset confidence 0.495 < 0.5"]
    entries = [{"p95": {}, "align": {"offset_confidence": 0.31}}]
    _outliers(entries)
    assert entries[0]["reasons"] == ["offset confidence 0.31 < 0.5"]
