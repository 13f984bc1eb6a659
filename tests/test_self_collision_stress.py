"""The self-collision guarantee under stress (benchmarks/self_collision_stress.py at the sizes the tests use), counted
exactly at every frame: a ribbon piling on the floor, a towel folded three times by pins, a sheet twisted by its
pinned edges, and a hanging sheet whose corners are jerked sideways.

A pile or a fold is chaotic: its exact outcome follows the last bits of its start (docs/performance.md, "Keeping clear
of chaos"). The guarantee holds at every frame (no crossing, no unresolved pair); whether a stray impact zone falls
in the last second does not, so the tests bound the share of the last second's steps that made one, well under the
three steps in four of a fold that locks."""
import pytest

from benchmarks.self_collision_stress import (crossings_per_frame, jerked_sheet, ribbon_pile, towel_folded_three_times,
                                             twisted_sheet)
from taichi_cloth.perturb import ROUND_OFF, perturb_start


#: the largest share of the last second's steps in which impact zones may hold a cloth said not to be held. A fold
#: that cannot open makes them in most steps (the jerked sheet at its fixed step below: 58-59 of its last 80 steps
#: where it locks); the stress scenes, each run from its start and from 3 starts moved by 1e-7 m
#: (taichi_cloth.perturb), made them in at most 2 of the last 60 steps (the towel from one moved start; the others
#: none), and the ribbon in 4 zones, so at most 4 steps, on another CPU; with friction in the implicit solve (a
#: sliding contact's dashpot) the towel folded three times made them in 16 of its last 60: 40 % is about half the
#: locked fold's share
HELD_SHARE = 0.4


def held_steps_in_last(obj, seconds: float) -> tuple[int, int]:
    """(steps that made an impact zone, steps) over the last `seconds` [s] of steps of SelfCollision `obj`."""
    zones = obj.recent_zones(seconds)
    return sum(z > 0 for z in zones), len(zones)


@pytest.mark.parametrize("build, frames, step", [(ribbon_pile, 90, "fixed"), (towel_folded_three_times, 240, "fixed"),
                                                 (twisted_sheet, 90, "auto")],
                         ids=["ribbon pile", "towel folded three times", "twisted sheet"])
def test_the_cloth_never_crosses_itself_at_any_frame(build, frames, step):
    """The small stress scenes (benchmarks/self_collision_stress.py): without self-collision the cloth passes
    through itself (the ribbon within 30 frames, the towel by its second fold, the twisted sheet at 1.27 s); with it,
    no two triangles intersect at any of the frames (1.5 s of the ribbon, 4 s of the towel, the twist's first 1.5 s at
    the adaptive step), the continuous stage left no pair unresolved, and impact zones do not hold the cloth at its end:
    they were made in at most a quarter of the last second's steps (HELD_SHARE; a locked fold makes them in most
    steps). Which steps make a stray zone is chaotic: the towel from a start moved by 1e-7 m made 3 zones in its last
    second, the ribbon 4 on another CPU, where the unmoved starts here make none."""
    without, _ = build(False, small=True, step=step)
    assert crossings_per_frame(without, frames, stop_at_first=True)[-1] > 0
    scene, n = build(True, small=True, step=step)
    assert n >= frames
    assert max(crossings_per_frame(scene, frames)) == 0
    obj = scene.controller("colliders").self_collision
    assert obj.counter_values()["unresolved pairs"] == 0
    held, steps = held_steps_in_last(obj, 1.0)
    assert steps >= 60 and held <= HELD_SHARE * steps, (held, steps)  # nothing held at the end


def test_a_run_still_held_by_impact_zones_at_its_end_says_so():
    """The small jerked sheet (16 x 16) at its fixed step of 1/240 s folds over itself in its own plane; the fold
    cannot open without crossing, so impact zones hold it in most steps after the first few, and the summary of a
    third of a second warns, with the adaptive step as the way out (the stress scenes above end with none). Whether
    the fold locks is chaotic: from its start and 3 starts moved by 1e-7 m (seeds 1-3), impact zones in 59, 0, 20 and
    58 of the last 80 steps (strain 130, 5, 62, 89 %). So the starts are tried in that order until one is held (the
    first, here): each one's summary warns exactly when zones were made in its last second, with their count."""
    for seed in (None, 1, 2, 3):
        jerked, _ = jerked_sheet(True, small=True, step="fixed")
        if seed is not None:
            perturb_start(jerked, ROUND_OFF, seed)
        summary = jerked.run(20, progress=False)
        zones = jerked.controller("colliders").self_collision.zones_in_last(1.0)
        held = [w for w in summary.warnings if w.startswith("self-collision held parts of the cloth in")]
        assert len(held) == (zones > 0), (zones, held)  # it warns exactly when held
        assert summary.host_reads_steps == 0  # its impact zones are made on the device, with no read
        if held:
            break
    assert held, "none of 4 starts of the jerked sheet locked at its fixed step"
    assert f"in {zones} impact zones in the run's last second" in held[0]
    assert summary.stats["self-collision impact zones per step"] > 0
    assert 'dt = "auto" in [integrator], with adaptive = { dt_max = 0.00417 }' in held[0]  # the way out (below)


def test_a_jerked_sheet_at_the_adaptive_step_does_not_lock():
    """The same jerk at dt = "auto" with 1/240 s as the longest step: the motion rule halves the step while the sheet
    moves fast, so the continuous stage's responses stay small, and after 2 s the sheet hangs with its springs back
    near the hung sheet's 0.88 % strain and impact zones in at most a quarter of the last second's steps (at the fixed
    step above it locks with over 100 % strain). From its start and 3 starts moved by 1e-7 m: 0.80-1.05 % strain (the
    bound of 1.5 % lies 0.45 % above the worst, nearly twice the spread) and no impact zone in the last second's
    357-618 steps."""
    scene, _ = jerked_sheet(True, small=True, step="auto")
    crossings = crossings_per_frame(scene, 120)
    assert max(crossings) == 0
    assert scene.measure().max_strain < 0.015
    held, steps = held_steps_in_last(scene.controller("colliders").self_collision, 1.0)
    assert steps >= 240 and held <= HELD_SHARE * steps, (held, steps)
