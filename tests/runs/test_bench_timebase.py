"""`manus bench timebase` on one null recording per rate: nothing found on the clean recording,
each corruption found (and a device's log keeps every row)."""

from argparse import Namespace

from manus.runs.bench import timebase


def test_the_time_base_bench_finds_each_corruption_and_nothing_on_the_clean_recording():
    r = timebase.run(Namespace(seeds=1, rates="1000,100", fit_seeds=0))
    f = r["figures"]
    assert f["recordings"] == 2 and f["clean_found"] == 0
    assert all(f[f"{name.replace(' ', '_')}_found"] == 2 for name in timebase.CORRUPTIONS), f
    text = timebase.render(r)
    assert "device log" in text and "0/2 found" in text
