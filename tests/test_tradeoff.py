"""The speed/accuracy study (`bench tradeoff`) on a tiny sweep: its table, the physics it must show (a convergent
integrator's error falls with its step; an explicit step beyond the bound is recorded as unstable), the Pareto
front, the presets derived from it and the files it writes. Speed itself is never asserted."""
import csv

import numpy as np
import pytest

from benchmarks import tradeoff as tr
from benchmarks.accuracy import Trajectory, compare, pareto_front, surface_distance
from taichi_cloth.integrators import INTEGRATORS
from taichi_cloth.quality import load_presets

pytestmark = pytest.mark.slow  # each builds a small trade-off study against an implicit reference (tens of seconds)

STEPS = (1 / 30, 1 / 60, 1 / 120)
FRACTIONS = (0.9, 0.3)


@pytest.fixture(scope="module")
def study():
    return tr.run_study(["hanging"], ["explicit", "implicit"], levels_below=(0, 1), base=2, n_levels=3,
                        sim_time=0.4, samples=4, ref_dt=5e-4, dts=STEPS, fractions=FRACTIONS,
                        explicit_tried=(1 / 60,), progress=False, log=lambda *a: None)


def rows_of(study, variant, level=3):
    return [r for r in study.rows if r["variant"] == variant and r["level"] == level]


def test_every_configuration_is_one_row_with_every_column(study):
    # 2 levels x (implicit: 3 steps + explicit: 1 frame-sized step and 2 bound fractions)
    assert len(study.rows) == 2 * (len(STEPS) + 1 + len(FRACTIONS))
    names = [k for k, _ in tr.COLUMNS]
    for r in study.rows:
        assert set(names) <= set(r)
    assert tr.markdown_table(study.rows).splitlines()[0] == "| " + " | ".join(names) + " |"
    assert {r["particles"] for r in study.rows} == {25, 13}  # 4-8 levels 3 and 2 of a 2x2 base


def test_the_error_of_a_convergent_integrator_falls_with_its_step(study):
    implicit = sorted(rows_of(study, "implicit"), key=lambda r: -r["dt"])
    errors = [r["rms_error"] for r in implicit]
    assert all(r["stable"] for r in implicit)
    assert errors[0] > errors[1] > errors[2]
    # each halving of h cuts the error by 2.6x and 3.4x here (measured), well clear of the reference's own error
    assert all(a / b > 2.0 for a, b in zip(errors, errors[1:]))
    assert [r["energy_drift"] for r in implicit] == sorted((r["energy_drift"] for r in implicit), reverse=True)
    explicit = sorted((r for r in rows_of(study, "explicit") if r["stable"]), key=lambda r: -r["dt"])
    assert len(explicit) == len(FRACTIONS) and explicit[0]["rms_error"] > explicit[1]["rms_error"]


def test_an_explicit_step_beyond_the_bound_is_recorded_unstable(study):
    for level in (2, 3):
        frame = [r for r in rows_of(study, "explicit", level) if r["step"] == "1/60 s"]
        assert len(frame) == 1 and frame[0]["dt"] > frame[0]["stable_dt"]
        assert not frame[0]["stable"] and frame[0]["status"].startswith("unstable at t = ")
        assert np.isnan(frame[0]["rms_error"]) and not frame[0]["front"]
        for r in rows_of(study, "explicit", level):
            if r["step"] != "1/60 s":
                assert r["stable"] and r["dt"] <= 0.9 * r["stable_dt"] * (1 + 1e-12)


def test_the_reference_resolves_its_window(study):
    ref = study.references["hanging"]
    assert ref.window == 4  # before it folds, the swing is resolved at every sample (0.2-0.4 mm measured)
    assert np.all(ref.sample_floor[:ref.window] <= tr.FLOOR)
    assert ref.floor["rms_error"] <= tr.FLOOR
    # every stable configuration is farther from the reference than the reference's own error estimate
    assert min(r["rms_error"] for r in study.rows if r["stable"]) > 0.5 * ref.floor["rms_error"]


def test_the_front_is_exactly_the_set_no_configuration_beats(study):
    stable = [r for r in study.rows if r["stable"]]
    for r in stable:
        beaten = any(o["wall_per_sim_s"] <= r["wall_per_sim_s"] and o["rms_error"] <= r["rms_error"]
                     and (o["wall_per_sim_s"], o["rms_error"]) != (r["wall_per_sim_s"], r["rms_error"]) for o in stable)
        assert r["front"] == (not beaten)
    assert list(pareto_front([1, 2, 3, np.nan, 2], [3, 1, 2, 0, 1])) == [True, True, False, False, False]


def test_presets_come_from_the_front_in_order_of_cost(study, tmp_path):
    presets, text = tr.write_outputs(study, tmp_path)
    agg = tr.aggregate(study)
    front = {(r["variant"], r["level"], r["step"]) for r in agg if r["front"]}
    costs, errors = [], []
    for name in ("preview", "balanced", "accurate"):
        p = presets[name]
        assert p["integrator"] in INTEGRATORS and p["level"] in (-1, 0)
        step = f"{p['dt_bound_fraction']:g} x bound" if "dt_bound_fraction" in p else f"1/{1 / p['dt']:.0f} s"
        assert (p["variant"], p["level"] + 3, step) in front
        costs.append(p["measured"]["wall_per_sim_s_all_scenes"])
        errors.append(p["measured"]["worst_rms_error_m"])
        if p["met"]:
            assert errors[-1] <= tr.PRESET_ERRORS[name]
    assert costs == sorted(costs) and errors == sorted(errors, reverse=True)
    # the files: a CSV with the table's columns, the presets in the format `run --quality` reads
    with open(tmp_path / "tradeoff.csv") as fh:
        header = next(csv.reader(fh))
    assert header[:len(tr.COLUMNS)] == [k for k, _ in tr.COLUMNS]
    loaded = load_presets(tmp_path / "presets.toml")
    assert loaded["accurate"].integrator == presets["accurate"]["integrator"]
    assert "## Presets" in text and (tmp_path / "tradeoff.png").stat().st_size > 0
    assert (tmp_path / "tradeoff.rrd").stat().st_size > 0


def test_surface_distance_ignores_sliding_but_not_lifting():
    g = np.linspace(0.0, 1.0, 6)
    u, v = np.meshgrid(g, g)
    x = np.c_[u.ravel(), np.zeros(36), v.ravel()]
    k = np.arange(36).reshape(6, 6)[:-1, :-1].ravel()
    tri = np.r_[np.c_[k, k + 1, k + 7], np.c_[k, k + 7, k + 6]]
    assert surface_distance(x, tri, x + [0.0, 0.01, 0.0], tri) == pytest.approx((0.01, 0.01), abs=1e-12)
    slid = x.copy()
    slid[7:11, 0] += 0.05  # interior vertices moved within the plane: the surface is the same
    assert surface_distance(x, tri, slid, tri) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_energy_growth_is_energy_above_the_start():
    times = np.array([0.1, 0.2, 0.3])
    x = np.zeros((3, 4, 3))
    ref = Trajectory(times, x, np.array([1.0, 0.8, 0.7]), start_energy=1.0)
    calm = Trajectory(times, x, np.array([0.9, 0.8, 0.6]), start_energy=1.0)
    rising = Trajectory(times, x, np.array([0.9, 1.3, 1.1]), start_energy=1.0)
    assert compare(calm, ref, 2.0)["energy_growth"] == 0.0
    assert compare(rising, ref, 2.0)["energy_growth"] == pytest.approx(0.15)
    assert compare(rising, ref, 2.0)["energy_drift"] == pytest.approx(0.25)
    assert tr.ENERGY_GROWTH < 0.15  # such a run would be reported as having gained energy


def test_bad_options_get_one_error_line(capsys):
    from taichi_cloth.cli import main

    assert main(["bench", "tradeoff", "--variants", "rk4"]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: unknown variant 'rk4'") and "error" not in captured.out
    assert main(["bench", "tradeoff", "--sim-time", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: ")
