"""`manus stability` end to end on a small grid, its errors, and the logic that checks the
thesis's sensitivity claims."""

import json

import pytest

from manus.experiments.stability.sensitivity import check
from manus.experiments.stability.steptest import TYPE2
from manus.runs import cli


def test_stability_command_json(tmp_path, capsys):
    code = cli.main(
        [
            "stability",
            "--json",
            "--b-c",
            "0",
            "35",
            "5",
            "--k",
            "500",
            "4500",
            "1000",
            "--no-sensitivity",
            "--no-appendix-d",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    poles = sorted(r["eq41_poles"]["poles"])
    assert poles[0][0] == pytest.approx(-186.5, abs=0.05)
    assert set(r["type1"]["continuous"]) == {"0", "1050", "1883", "3826", "9842", "34660", "130900"}
    assert r["type1"]["continuous"]["0"][0] == pytest.approx(1500.4, rel=1e-3)  # b_c = 0: b/τ, about
    m = r["map"]
    assert m["points"] == 8 * 5 and m["type1_boundary"] and m["type2_boundary"]
    assert m["type1_slope"] > 0 > m["type2_slope"]  # the thesis's shape
    assert -1.5 < r["negative_damping"]["limit"] < -1.4 and r["negative_damping"]["thesis"] == -1.5
    assert set(r["psd_conventions"]) == {"fft |X|^2/N (ours)", "one-sided density m^2/Hz", "Welch Hann-256"}
    for path in r["figures"].values():
        assert (tmp_path / path.split("/")[-1]).exists()


def test_bad_grid_is_a_one_line_error(capsys):
    assert cli.main(["stability", "--k", "0", "100", "10"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--k" in err and "MIN > 0" in err and "\n" not in err


def _row(value, limit, kind, step=10.0):
    return {"value": value, "probes": [{"probe": "k at b_c=20", "limit": limit, "step": step, "kind": kind}]}


def test_claim_check_reads_exact_values_and_bounds():
    up = [_row(1, 1000.0, "type2"), _row(2, 2000.0, "type2"), _row(3, 3000.0, "type2")]
    assert check(up, "x raises", TYPE2, "up", "up")["verdict"] == "reproduced"
    assert check(up, "x lowers", TYPE2, "up", "down")["verdict"] == "contradicted"
    flat = [_row(1, 1000.0, "type2"), _row(2, 1005.0, "type2")]
    assert check(flat, "x raises", TYPE2, "up", "up")["verdict"] == "unchanged"  # within the resolution
    # at value 3 Type 1 came first at 5000: Type 2 lies above 5000, so it rose from 2000
    bound = [_row(2, 2000.0, "type2"), _row(3, 5000.0, "type1")]
    assert check(bound, "x raises", TYPE2, "up", "up")["probes"] == {"k at b_c=20": "as claimed"}
    # ... but a bound below the other value decides nothing
    assert (
        check([_row(2, 2000.0, "type2"), _row(3, 1500.0, "type1")], "", TYPE2, "up", "up")["verdict"]
        == "not comparable"
    )
    mixed = [_row(0, 6000.0, "type2"), _row(1, 2500.0, "type2"), _row(2, 2800.0, "type2")]
    assert check(mixed, "less x raises", TYPE2, "down", "up")["verdict"] == "not reproduced"
    two = [
        {"value": r["value"], "probes": r["probes"] + [u["probes"][0] | {"probe": "k at b_c=30"}]}
        for r, u in zip(mixed, up, strict=False)
    ]
    assert check(two, "", TYPE2, "up", "up")["verdict"] == "partly"  # one probe rises, one is mixed


def test_bench_stability_reports_both_ways_and_the_speedup(capsys):
    assert cli.main(["bench", "stability", "--json", "--points", "128", "--loop-points", "2", "--repeats", "1"]) == 0
    r = json.loads(capsys.readouterr().out)
    f = r["figures"]
    assert f["vmapped_points_per_s"] > 0 and f["loop_points_per_s"] > 0
    assert r["speedup"] == pytest.approx(f["vmapped_points_per_s"] / f["loop_points_per_s"])
    assert r["ticks_per_point"] == 5000 and r["substeps_per_tick"] == 10
