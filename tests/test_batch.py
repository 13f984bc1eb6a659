"""`python -m taichi_cloth batch`: a 1 x 2 batch of the skirt on the process pool (statuses, table columns, files,
a worker killed once and retried), a rerun that runs nothing, jobs whose worker dies or raises becoming error
rows, the scheduler's retry, timeout and Ctrl-C on a stand-in backend, the spec's one-line errors, and the same
batch on a local Ray cluster when ray is installed (the `cluster` extra; skipped without it)."""
import importlib.util
from pathlib import Path

import pytest

from taichi_cloth.batch import schedule
from taichi_cloth.batch.figures import ERROR, OK, SEAMS_OPEN, TIMED_OUT
from taichi_cloth.batch.jobs import make_jobs
from taichi_cloth.batch.spec import BatchError, load_spec
from taichi_cloth.batch.table import COLUMNS, read_table
from taichi_cloth.batch.worker import FAULT_ENV, read_row
from taichi_cloth.cli import main

GARMENTS = Path(__file__).resolve().parents[1] / "demos" / "garments"

#: the skirt on a body smaller than the mannequin, in cotton and in denim: 40 frames at most, a loose rest
#: criterion (at rest once the seams are joined, about frame 33 in either); the denim job is capped at 12 frames,
#: where its panels are still centimetres apart. No pictures: the sheet's cells are the jobs' reasons (the
#: pictures cost 1.7 s a job).
TINY = f"""
garments = ["{GARMENTS / 'skirt.toml'}"]
bodies = [{{ name = "small", waist = 62, hips = 90 }}]
materials = ["cotton", "denim"]

[run]
frames = 40
png = false
rest = {{ max_speed = 0.5, p99_speed = 0.5, hold = 0.05, window = 0.05 }}

[[jobs]]
garment = "skirt"
body = "small"
material = "cotton"

[[jobs]]
garment = "skirt"
body = "small"
material = "denim"
run = {{ frames = 12 }}
"""


def write_spec(folder: Path, text: str, name: str = "tiny.toml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The 1 x 2 batch run once on two workers, its first job's worker killed on its first attempt."""
    folder = tmp_path_factory.mktemp("batch")
    spec = write_spec(folder, TINY)
    out = folder / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(FAULT_ENV, "skirt_small_cotton=exit-once")
        assert main(["batch", str(spec), "--workers", "2", "--out", str(out)]) == 0
    return spec, out


def test_a_batch_writes_a_row_per_job_with_its_status_the_table_and_the_sheet(tiny):
    spec, out = tiny
    rows = {r["label"]: r for r in read_table(out / "results.parquet")}
    assert list(rows) == ["skirt_small_cotton", "skirt_small_denim"]  # the jobs' order
    assert {k: r["status"] for k, r in rows.items()} == {"skirt_small_cotton": OK, "skirt_small_denim": SEAMS_OPEN}
    assert rows["skirt_small_denim"]["reason"].startswith("still sewing at the frame cap; left side")
    # the worker killed midway was started again and finished; the other ran once
    assert [r["attempts"] for r in rows.values()] == [2, 1]
    names = [n for n, _ in COLUMNS if not n.endswith("_cm")] + ["waist_cm", "hips_cm"]
    header = (out / "results.csv").read_text().splitlines()[0].replace('"', "").split(",")
    assert set(names) <= set(header) and {"area_error_front", "area_error_back"} <= set(header)
    assert len((out / "results.csv").read_text().splitlines()) == 3
    ok = rows["skirt_small_cotton"]
    assert ok["waist_cm"] == 62 and ok["hips_cm"] == 90 and "chest_cm" not in ok  # only the girths given
    assert ok["rest_time_s"] > 0 and ok["steps"] == 2 * ok["frames"] and ok["frames"] < 40
    assert ok["inside"] == 0 and ok["seam_gap_max_mm"] == 0 and 0 < ok["max_strain"] < 0.2
    assert ok["gap_chest_mm"] is None and ok["gap_waist_mm"] is not None  # a skirt: no cloth at the chest
    for job in make_jobs(load_spec(spec, out)):
        files = sorted(p.name for p in Path(job.dir).iterdir())
        assert files == sorted(["log.txt", "row.json", f"{job.label}.obj", f"{job.label}.ply"])
    assert (out / "contact_sheet.png").stat().st_size > 0


def test_a_rerun_skips_every_finished_job(tiny, capsys, monkeypatch):
    spec, out = tiny
    started = []
    monkeypatch.setattr(schedule, "clear_outputs", lambda folder: started.append(folder))
    before = (out / "results.csv").read_text()
    assert main(["batch", str(spec), "--out", str(out)]) == 0
    assert started == []
    assert "2 jobs, 2 done before, 0 to run" in capsys.readouterr().out
    assert (out / "results.csv").read_text() == before
    assert main(["batch", str(spec), "--out", str(out), "--list"]) == 0
    assert capsys.readouterr().out.count(" ok\n") == 1


def test_a_job_that_kills_its_worker_twice_or_raises_is_an_error_row_and_the_rest_finish(tmp_path, monkeypatch):
    """The fault hook fires before Taichi starts: no job here builds a scene."""
    spec = write_spec(tmp_path, f"""
garments = ["{GARMENTS / 'skirt.toml'}"]
bodies = ["mannequin", {{ name = "b", waist = 62 }}, {{ name = "c", waist = 64 }}]
[[jobs]]
garment = "skirt"
[[jobs]]
garment = "skirt"
body = "b"
[[jobs]]
garment = "skirt"
body = "c"
""")
    monkeypatch.setenv(FAULT_ENV, "skirt_mannequin_garment=exit,skirt_b_garment=raise,skirt_c_garment=raise")
    assert main(["batch", str(spec), "--workers", "2", "--out", str(tmp_path / "out")]) == 0
    rows = read_table(tmp_path / "out" / "results.parquet")
    assert [(r["label"], r["status"], r["attempts"]) for r in rows] == [
        ("skirt_mannequin_garment", ERROR, 2), ("skirt_b_garment", ERROR, 1), ("skirt_c_garment", ERROR, 1)]
    assert rows[0]["reason"] == "the worker died in both attempts (exit code 70)"
    assert rows[1]["reason"] == f"RuntimeError: fault injected by {FAULT_ENV}"
    assert "Traceback" in (Path(make_jobs(load_spec(spec, tmp_path / "out"))[1].dir) / "log.txt").read_text()


class StandIn:
    """A backend whose jobs end as told: {label: [outcome per attempt]}: a row's status, "die", or "hang"."""

    name, capacity = "stand-in", 2

    def __init__(self, script, interrupt_after=None):
        self.script, self.running, self.closed, self.killed = script, {}, False, []
        self.interrupt_after, self.waits = interrupt_after, 0

    def start(self, job, attempt):
        handle = (job["label"], attempt)
        self.running[handle] = job
        return handle

    def wait(self, timeout):
        self.waits += 1
        if self.interrupt_after is not None and self.waits > self.interrupt_after:
            raise KeyboardInterrupt
        out = []
        for (label, attempt), job in list(self.running.items()):
            outcome = self.script[label][attempt - 1]
            if outcome == "hang":
                continue
            del self.running[(label, attempt)]
            out.append(((label, attempt), None, "killed by SIGKILL") if outcome == "die" else
                       ((label, attempt), {"label": label, "status": outcome, "attempts": attempt}, None))
        return out

    def kill(self, handle):
        self.killed.append(handle)
        del self.running[handle]

    def close(self):
        self.closed = True


def stand_in_jobs(*labels, timeout=60.0):
    return [{"label": label, "key": label, "garment": "g", "body": "b", "material": "m", "girths": {},
             "dir": f"/nonexistent/{label}", "run": {"timeout": timeout}} for label in labels]


def test_the_scheduler_retries_a_dead_worker_once_stops_a_job_past_its_timeout_and_stops_on_ctrl_c(monkeypatch):
    monkeypatch.setattr(schedule, "clear_outputs", lambda folder: None)
    monkeypatch.setattr(schedule, "TICK", 0.0)
    rows = {}
    backend = StandIn({"a": ["die", OK], "b": ["die", "die"], "c": [SEAMS_OPEN]})
    schedule.run_jobs(stand_in_jobs("a", "b", "c"), backend, lambda job, row: rows.update({job["label"]: row}),
                      schedule.Progress(3, 0, 2))
    assert {k: (r["status"], r["attempts"]) for k, r in rows.items()} == {
        "a": (OK, 2), "b": (ERROR, 2), "c": (SEAMS_OPEN, 1)}
    assert rows["b"]["reason"] == "the worker died in both attempts (killed by SIGKILL)"

    rows.clear()
    backend = StandIn({"slow": ["hang"], "quick": [OK]})
    schedule.run_jobs(stand_in_jobs("slow", "quick", timeout=0.0), backend,
                      lambda job, row: rows.update({job["label"]: row}), schedule.Progress(2, 0, 2))
    assert rows["slow"]["status"] == TIMED_OUT and backend.killed == [("slow", 1)]

    rows.clear()
    backend = StandIn({"a": [OK], "b": ["hang"], "c": [OK]}, interrupt_after=1)
    with pytest.raises(KeyboardInterrupt):
        schedule.run_jobs(stand_in_jobs("a", "b", "c"), backend, lambda job, row: rows.update({job["label"]: row}),
                          schedule.Progress(3, 0, 2))
    assert list(rows) == ["a"] and backend.closed  # what finished is kept; what ran is stopped


def test_a_garment_that_names_its_bodies_is_fitted_to_those_only(tmp_path):
    """The garment matrix's form: each garment on the bodies of its size range, every material."""
    spec = write_spec(tmp_path, f"""
garments = [{{ file = "{GARMENTS / 'skirt.toml'}", bodies = ["mannequin", "S60"] }}, "{GARMENTS / 'top.toml'}"]
materials = ["silk", "denim"]
bodies = ["mannequin", {{ name = "S60", waist = 60, hips = 88 }}, {{ name = "T80", chest = 80 }}]
""")
    labels = [job.label for job in make_jobs(load_spec(spec, tmp_path / "out"))]
    assert labels == ["skirt_mannequin_silk", "skirt_S60_silk", "skirt_mannequin_denim", "skirt_S60_denim",
                      "top_mannequin_silk", "top_S60_silk", "top_T80_silk", "top_mannequin_denim", "top_S60_denim",
                      "top_T80_denim"]


def test_moved_starts_run_each_job_once_per_seed_and_the_worker_moves_its_start(tmp_path, monkeypatch):
    """[run] perturb and seeds (the garment matrix's rest margins): a job per seed, each its own key and label, the
    worker handing the distance and the seed to the run (taichi_cloth.perturb); without perturb the keys are the
    plain batch's (its finished jobs are not run again)."""
    from taichi_cloth.batch import worker

    body = f'garments = ["{GARMENTS / "skirt.toml"}"]\nmaterials = ["silk"]\n'
    plain = make_jobs(load_spec(write_spec(tmp_path, body, "plain.toml"), tmp_path / "out"))
    moved = make_jobs(load_spec(write_spec(tmp_path, body + "[run]\nperturb = 1e-7\nseeds = [1, 2, 3]\n",
                                           "moved.toml"), tmp_path / "out"))
    assert [j.label for j in plain] == ["skirt_mannequin_silk"]
    assert [j.label for j in moved] == [f"skirt_mannequin_silk_seed{k}" for k in (1, 2, 3)]
    assert len({j.key for j in moved} | {plain[0].key}) == 4
    assert [(j.run["perturb"], j.run["seed"]) for j in moved] == [(1e-7, 1), (1e-7, 2), (1e-7, 3)]
    assert "perturb" not in plain[0].run
    seen = []
    monkeypatch.setattr(worker, "run_scene_file", lambda scene, args, **kw: seen.append((args.perturb, args.seed))
                        or (_ for _ in ()).throw(OSError("stop here")))
    assert worker.execute(moved[1].as_dict())["status"] == ERROR
    assert seen == [(1e-7, 2)]
    with pytest.raises(BatchError, match="seeds .*nothing to seed without perturb"):
        make_jobs(load_spec(write_spec(tmp_path, body + "[run]\nseeds = [1]\n", "bad.toml"), tmp_path / "out"))


@pytest.mark.parametrize("text, message", [
    ("garments = []", "garments: must be a non-empty list"),
    ('garments = ["nowhere.toml"]', "garments #1: "),
    (f'garments = ["{GARMENTS / "skirt.toml"}"]\nbodies = [{{ name = "x", wasit = 60 }}]',
     "bodies #1: unknown key 'wasit' (did you mean 'waist'?)"),
    (f'garments = ["{GARMENTS / "skirt.toml"}"]\nmaterials = ["tweed"]', "materials #1: 'tweed' is not one of"),
    (f'garments = ["{GARMENTS / "skirt.toml"}"]\n[[jobs]]\ngarment = "tshirt"',
     "[[jobs]] #1 garment: 'tshirt' is not one of the batch's garments: skirt"),
    (f'garments = ["{GARMENTS / "skirt.toml"}"]\n[run]\nframs = 3', "[run]: unknown key 'frams'"),
    (f'garments = [{{ file = "{GARMENTS / "skirt.toml"}", bodies = ["S"] }}]',
     "garments #1 bodies: 'S' is not one of the batch's bodies: mannequin"),
])
def test_a_bad_spec_is_one_line_naming_the_key(tmp_path, capsys, text, message):
    spec = write_spec(tmp_path, text)
    with pytest.raises(BatchError, match=None) as err:
        load_spec(spec)
    assert message in str(err.value) and str(spec) in str(err.value)
    assert main(["batch", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None, reason="ray is installed")
def test_ray_without_ray_says_how_to_install_it(tiny, tmp_path, capsys):
    spec, _ = tiny
    assert main(["batch", str(spec), "--ray", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == "error: --ray needs ray, which is not installed: pip install -e '.[cluster]'\n"


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="needs the cluster extra (ray)")
def test_the_same_batch_on_a_local_ray_cluster_gives_the_same_table(tiny, tmp_path):
    spec, out = tiny
    assert main(["batch", str(spec), "--ray", "--workers", "2", "--out", str(tmp_path / "ray")]) == 0
    pool = read_table(out / "results.parquet")
    ray = read_table(tmp_path / "ray" / "results.parquet")
    assert [(r["key"], r["status"]) for r in ray] == [(r["key"], r["status"]) for r in pool]
    for a, b in zip(ray, pool):
        assert a["outputs"] == b["outputs"] and a["particles"] == b["particles"]
        assert a["frames"] == pytest.approx(b["frames"], abs=3)
    assert read_row(Path(make_jobs(load_spec(spec, tmp_path / "ray"))[0].dir))["status"] == OK


def test_the_garment_matrix_counts_a_job_steady_only_when_every_moved_start_rests_in_time():
    """benchmarks.garment_matrix.table: an ok job with all its moved starts ok gives its rest-time range; one whose
    moved start is still moving, or rests after REST_WITHIN, is named "moved: k of n" and not counted steady; a job
    too small for its body is not counted at all."""
    from benchmarks.garment_matrix import REST_WITHIN, table

    def row(body, material, status="ok", rest=2.0):
        return {"garment": "skirt", "body": body, "material": material, "status": status, "rest_time_s": rest,
                "reason": "" if status == "ok" else "too small: the waistband is 68 cm and the waist 80 cm"}

    plain = [row("A", "silk"), row("B", "silk"), row("C", "silk", "too small", None)]
    moved = [row("A", "silk", rest=1.5), row("A", "silk", rest=2.5), row("A", "silk", rest=3.0),
             row("B", "silk", rest=2.2), row("B", "silk", rest=REST_WITHIN + 0.1),
             row("B", "silk", "not at rest by the cap", None)]
    text, ok, counted, steady = table(plain, "2 cm", moved)
    assert (ok, counted, steady) == (2, 2, 1)
    assert "ok 1.50-3.00 s |" in text and "ok 2.00-2.20 s (moved: 1 of 3)" in text and "too small" in text
