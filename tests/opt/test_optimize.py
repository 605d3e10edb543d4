"""Design optimisation: the optimize and report commands as a user runs them, and their library."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import optuna
import pytest

from tests.helpers import interruptible, tb, tb_ok
from tumblebot.sim.optimize import (
    Objective,
    OptimizeError,
    Recipe,
    TrialNumberSampler,
    best_candidate,
    counted_trials,
    episode_count,
    full_batch_results,
    parse_tasks,
    parse_xi,
    posterior_ratings,
    promotion_scores,
    promotions,
    screen_scores,
    surrogate,
)
from tumblebot.sim.world.design import Design


def load(db: Path, name: str) -> optuna.Study:
    return optuna.load_study(study_name=name, storage=f"sqlite:///{db}")


# ------------------------------------------------------------------ parsing
def test_that_task_weights_parse_with_a_bare_name_weighing_one() -> None:
    assert parse_tasks("nav-flat=1,incline=0.5") == {"nav-flat": 1.0, "incline": 0.5}
    assert parse_tasks("nav-flat") == {"nav-flat": 1.0}
    assert parse_xi("3") == 3.0 and math.isinf(parse_xi("inf"))


@pytest.mark.parametrize(("text", "message"), [
    ("walk=1", "unknown task"), ("nav-flat=abc", "not a number"), ("nav-flat=-1", ">= 0"),
    ("nav-flat=nan", ">= 0"), ("nav-flat=0", "positive"), ("nav-flat=1,nav-flat=2", "twice"), ("", "empty"),
])
def test_that_bad_task_weights_get_one_clear_error(text: str, message: str) -> None:
    with pytest.raises(OptimizeError, match=message):
        parse_tasks(text)


@pytest.mark.parametrize("text", ["-1", "nan", "three"])
def test_that_bad_xi_is_refused(text: str) -> None:
    with pytest.raises(OptimizeError):
        parse_xi(text)


def test_that_the_thesis_recipe_is_the_thesis_schedule_and_cannot_be_bent() -> None:
    r = Recipe.make("thesis", None, None)
    assert (r.trials, r.startup, r.batch, r.screen_batch) == (2000, 1000, 240, 240)
    with pytest.raises(OptimizeError, match="fixes"):
        Recipe.make("thesis", 100, None)
    eff = Recipe.make("efficient", 300, 240)
    assert eff.screen_batch == 16 and eff.batch == 240


def test_that_the_objective_is_the_thesis_wrapper_summed_over_weighted_tasks() -> None:
    import numpy as np

    obj = Objective({"nav-flat": 1.0, "incline": 0.5}, 1.0)
    per = obj.per_episode({"nav-flat": np.array([0.5, 1.0]), "incline": np.array([0.2, 0.4])}, e=4.0)
    assert per == pytest.approx([0.5 / 5 + 0.5 * 0.2 / 5, 1.0 / 5 + 0.5 * 0.4 / 5])
    assert Objective({"nav-flat": 1.0}, math.inf).tasks == []


def test_that_screen_scores_smooth_only_the_noisy_part(tmp_path: Path) -> None:
    """A lucky batch among bad neighbours is pulled down; e(w) stays exact."""
    study = optuna.create_study(direction="maximize", storage=f"sqlite:///{tmp_path / 'k.db'}")
    dist: dict[str, optuna.distributions.BaseDistribution] = {n: optuna.distributions.FloatDistribution(*b) for n, b in
            {"x": (0.189, 0.3), "y": (0.102, 0.25), "z": (0.084, 0.2), "l": (0.066, 0.25)}.items()}
    for i, (leg, R) in enumerate([(0.150, [0.2] * 4), (0.152, [0.2] * 4), (0.154, [0.9] * 4), (0.240, [0.6] * 4)]):
        params = {"x": 0.2, "y": 0.11, "z": 0.09, "l": leg}
        t = optuna.trial.create_trial(params=params, distributions=dist, value=float(np.mean(R)),
                                      user_attrs={"R": {"nav-flat": R}, "e": 4.0 + i * 0.01})
        study.add_trial(t)
    scores = screen_scores(study, Objective({"nav-flat": 1.0}, 0.0))
    assert scores[2] < 0.5 < scores[3]  # the lone 0.9 has two 0.2 neighbours; the 0.6 stands alone
    xi1 = screen_scores(study, Objective({"nav-flat": 1.0}, 1.0))
    assert xi1[3] == pytest.approx(scores[3] / 5.03)


def test_that_start_up_designs_depend_on_the_trial_number_not_the_process() -> None:
    a, b = TrialNumberSampler(7), TrialNumberSampler(7)
    assert a.value(3, "x", 0.189, 0.3) == b.value(3, "x", 0.189, 0.3)
    assert a.value(3, "x", 0.189, 0.3) != a.value(4, "x", 0.189, 0.3)


# ------------------------------------------------------------------ the done-when commands
@pytest.mark.slow
def test_that_optimize_completes_resumes_and_reports(tmp_path: Path) -> None:
    db = tmp_path / "X.db"
    cmd = ["optimize", "--tasks", "nav-flat=1", "--xi", "3", "--trials", "12", "--batch", "8",
           "--storage", f"sqlite:///{db}", "--study", "s", "--seed", "0"]
    first = tb_ok(*cmd)
    assert "best robot" in first.stdout
    study = load(db, "s")
    assert counted_trials(study) == 12
    numbers = [t.number for t in study.trials]
    spent = episode_count(study)

    again = tb_ok(*cmd)  # the same command resumes: nothing to add, nothing redone
    assert "(0 episodes this run)" in again.stdout
    study = load(db, "s")
    assert [t.number for t in study.trials] == numbers and episode_count(study) == spent

    tb_ok(*[c if c != "12" else "14" for c in cmd])  # asking for more trials continues the study
    study = load(db, "s")
    assert counted_trials(study) == 14 and [t.number for t in study.trials][:len(numbers)] == numbers

    out = tmp_path / "DIR"
    tb_ok("report", "--storage", f"sqlite:///{db}", "--study", "s", "-o", str(out), "--workers", "2")
    text = (out / "report.md").read_text()
    for heading in ("Table 3.1 equivalent", "Table 3.2 equivalent", "Universal optimum", "Compared with the thesis"):
        assert heading in text
    for png in ("objective_vs_trial.png", "best_design_vs_trial.png", "slices.png", "energy.png"):
        assert (out / png).stat().st_size > 5000
    data = json.loads((out / "report.json").read_text())
    study = load(db, "s")
    best = best_candidate(study)
    # a study of full batches only (the standard recipe) takes its best full batch, no GP
    assert posterior_ratings(study, [t.number for t in study.trials]) == {}
    assert best is not None and best.value == max(c.value for c in full_batch_results(study))
    assert data["table31"][0]["design"] == pytest.approx(dict(zip("xyzl", best.design.as_tuple(), strict=True)))
    assert [r["change"] for r in data["table32"]] == ["none", "+x", "-x", "+y", "-y", "+z", "-z", "+l", "-l"]


@pytest.mark.slow
def test_that_infeasible_designs_are_recorded_cost_nothing_and_are_never_the_optimum(tmp_path: Path) -> None:
    db = tmp_path / "i.db"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "0", "--trials", "30", "--batch", "2", "--startup", "12",
          "--storage", f"sqlite:///{db}", "--study", "i", "--quiet")
    study = load(db, "i")
    infeasible = [t for t in study.trials if "infeasible" in t.user_attrs]
    assert infeasible, "seed 0 draws some designs with l < r among its start-up designs"
    for t in infeasible:
        w = Design(*(t.params[n] for n in "xyzl"))
        assert not w.can_tumble and "R" not in t.user_attrs
    # The GP learns the constraint: it does not keep proposing the infeasible corner.
    gp_phase = [t for t in study.trials if t.number >= 12]
    assert sum("infeasible" in t.user_attrs for t in gp_phase) <= len(gp_phase) // 2
    best = best_candidate(study)
    assert best is not None and best.design.can_tumble


def test_that_xi_infinity_minimises_e_without_any_episode(tmp_path: Path) -> None:
    db = tmp_path / "inf.db"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "25", "--batch", "240",
          "--storage", f"sqlite:///{db}", "--study", "inf", "--quiet")
    study = load(db, "inf")
    assert episode_count(study) == 0
    best = best_candidate(study)
    assert best is not None and best.value == pytest.approx(-best.e)
    assert best.e < 4.3  # the smallest robots are cheapest; thesis ξ = ∞ robot: 3.76 W/m


@pytest.mark.slow
def test_that_the_efficient_recipe_screens_then_promotes_to_the_full_batch(tmp_path: Path) -> None:
    db = tmp_path / "e.db"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "3", "--recipe", "efficient", "--trials", "24",
          "--batch", "60", "--storage", f"sqlite:///{db}", "--study", "e", "--quiet", "--workers", "2")
    study = load(db, "e")
    screened = [t for t in study.trials if "R" in t.user_attrs]
    assert all(len(t.user_attrs["R"]["nav-flat"]) == 4 for t in screened)
    promoted = promotions(study)
    assert promoted and all(len(p["R"]["nav-flat"]) == 60 for p in promoted.values())
    for number, p in promoted.items():  # a promotion keeps the screen's episodes and adds the shared ones
        assert p["R"]["nav-flat"][:4] == study.trials[number].user_attrs["R"]["nav-flat"]
    best = best_candidate(study)
    assert best is not None and best.batch == 60 and best.trial in promoted
    scores = promotion_scores(study, Objective({"nav-flat": 1.0}, 3.0), 3.0)
    hidden = surrogate.capped(surrogate.observations(study, {"nav-flat": 1.0}))  # their own episodes: worst tenth
    assert hidden and set(scores) == {t.number for t in screened} - hidden
    top = max(scores, key=lambda n: scores[n])
    assert top in promoted  # the most promising design (GP posterior) got its full batch before the end
    # the optimum is the full batch the GP rates best, not the luckiest 60 episodes
    rated = posterior_ratings(study, list(promoted))
    assert set(rated) == set(promoted) and best.trial == max(rated, key=lambda n: rated[n])
    assert best.trial == top


@pytest.mark.slow
def test_that_a_finished_efficient_study_run_again_adds_nothing(tmp_path: Path) -> None:
    """Each promotion moves the GP, so after the final promotions the designs it ranks on
    top need not all have their full batch. Running the finished study again used to
    promote those too, and the optimum could change from one run of the same command to
    the next."""
    from tumblebot.sim.optimize.search import _top_is_promoted

    db = tmp_path / "f.db"
    cmd = ["optimize", "--tasks", "nav-flat", "--xi", "3", "--gait", "goto", "--recipe", "efficient", "--trials",
           "40", "--batch", "12", "--seed", "3", "--workers", "2", "--storage", f"sqlite:///{db}", "--study", "f"]
    tb_ok(*cmd, "--quiet")
    study = load(db, "f")
    # what used to be promoted again (a study whose GP moves this way: most seeds' do not)
    assert not _top_is_promoted(study, Objective({"nav-flat": 1.0}, 3.0), 3, 3.0)
    promoted, spent, best = set(promotions(study)), episode_count(study), best_candidate(study)
    again = tb_ok(*cmd)
    assert "(0 episodes this run)" in again.stdout
    study = load(db, "f")
    assert set(promotions(study)) == promoted and episode_count(study) == spent and best_candidate(study) == best


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize(("args", "message"), [
    (["--tasks", "walk=1"], "unknown task"),
    (["--tasks", "nav-flat=x"], "not a number"),
    (["--tasks", "nav-flat=-2"], ">= 0"),
    (["--tasks", "nav-flat=nan"], ">= 0"),
    (["--batch", "0"], "--batch 0"),
    (["--trials", "0"], "--trials 0"),
    (["--xi", "-1"], "--xi"),
    (["--storage", "sqlite:////no/such/folder/x.db"], "does not exist"),
    (["--storage", "nosuchdb://x"], "cannot be opened"),
    (["--storage", "just-a-file.db"], "not a database URL"),
])
def test_that_bad_optimize_input_gets_one_clear_error(tmp_path: Path, args: list[str], message: str) -> None:
    base = {"--tasks": "nav-flat=1", "--xi": "3", "--trials": "3", "--batch": "2",
            "--storage": f"sqlite:///{tmp_path / 'b.db'}", "--study": "b"}
    for flag, value in zip(args[::2], args[1::2], strict=True):
        base[flag] = value
    run = tb("optimize", *[x for kv in base.items() for x in kv], "--quiet", timeout=120)
    assert run.returncode == 2
    assert message in run.stderr and "Traceback" not in run.stderr
    assert len([ln for ln in run.stderr.splitlines() if ln.startswith("tumblebot: error")]) == 1


def test_that_a_task_without_a_bundled_policy_is_refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    # All four tasks ship a policy now, so point the lookup at an empty folder (in-process).
    import tumblebot.sim.control.policy as policy
    from tumblebot.cli import main

    monkeypatch.setattr(policy, "bundled_policy", lambda task, layout=None: tmp_path / f"{task}.onnx")
    code = main(["optimize", "--tasks", "incline=1", "--xi", "3", "--trials", "3", "--batch", "2",
                 "--storage", f"sqlite:///{tmp_path / 'b.db'}", "--study", "b", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert "no bundled policy" in err and "Traceback" not in err
    assert len([ln for ln in err.splitlines() if ln.startswith("tumblebot: error")]) == 1


def test_that_a_study_made_for_another_objective_is_refused_and_left_untouched(tmp_path: Path) -> None:
    db = tmp_path / "s.db"
    base = ["--storage", f"sqlite:///{db}", "--study", "s", "--trials", "3", "--batch", "240", "--quiet"]
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", *base)
    before = load(db, "s")
    snapshot = ([(t.number, t.state, t.params, t.value) for t in before.trials], before.user_attrs)
    for other in (["--tasks", "nav-flat", "--xi", "3"], ["--tasks", "nav-flat=2", "--xi", "inf"],
                  ["--tasks", "nav-flat,distance-flat", "--xi", "inf"]):
        run = tb("optimize", *other, *base)
        assert run.returncode == 2 and "different objective" in run.stderr, run.stderr
    after = load(db, "s")
    assert ([(t.number, t.state, t.params, t.value) for t in after.trials], after.user_attrs) == snapshot


def test_that_report_refuses_a_missing_study(tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "2", "--batch", "2",
          "--storage", f"sqlite:///{db}", "--study", "here", "--quiet")
    run = tb("report", "--storage", f"sqlite:///{db}", "--study", "gone", "-o", str(tmp_path / "out"))
    assert run.returncode == 2 and "does not exist" in run.stderr and "here" in run.stderr


# ------------------------------------------------------------------ Ctrl-C
def _complete_trials(db: Path, study: str) -> int:
    try:
        return sum(t.state == optuna.trial.TrialState.COMPLETE for t in load(db, study).trials) if db.exists() else 0
    except Exception:  # the study may not exist yet
        return 0


def _wait_for_a_complete_trial(proc: subprocess.Popen[str], db: Path, study: str) -> None:
    """Wait (on the event, not a clock: a busy machine may take minutes) until ``proc`` has
    completed a trial of ``study`` in ``db``; fail if it ends first or none comes within a
    generous bound."""
    before = _complete_trials(db, study)
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        time.sleep(0.5)
        assert proc.poll() is None, f"the run ended before any trial completed: {proc.communicate()[1][-2000:]}"
        if _complete_trials(db, study) > before:
            return
    raise AssertionError("no trial completed within 600 s")


@pytest.mark.slow
def test_that_ctrl_c_stops_cleanly_and_the_same_command_resumes(tmp_path: Path) -> None:
    db = tmp_path / "c.db"
    cmd = [sys.executable, "-m", "tumblebot.cli", "optimize", "--tasks", "nav-flat", "--xi", "0", "--trials", "8",
           "--batch", "24", "--storage", f"sqlite:///{db}", "--study", "c", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            preexec_fn=interruptible)
    _wait_for_a_complete_trial(proc, db, "c")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Run the same command to resume" in err and "Traceback" not in err
    study = load(db, "c")
    done = counted_trials(study)
    assert 1 <= done < 8
    assert all(t.state != optuna.trial.TrialState.RUNNING for t in study.trials)
    resumed = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False, stdin=subprocess.DEVNULL)
    assert resumed.returncode == 0, resumed.stderr
    assert counted_trials(load(db, "c")) == 8


def _interrupt_at(cmd: list[str], delay: float) -> subprocess.CompletedProcess[str]:
    """Start ``cmd`` with Ctrl-C at its default (a background job of a non-interactive shell
    would inherit it ignored), send SIGINT ``delay`` s after start, wait for it to end."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            preexec_fn=interruptible)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=300)  # generous: a hang, not a slow machine, fails this
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"the process did not exit after Ctrl-C at {delay} s: {err[-2000:]}") from None
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["1", "2"])
def test_that_ctrl_c_at_any_moment_never_strands_a_trial_nor_hangs(tmp_path: Path, workers: str) -> None:
    db = tmp_path / "m.db"
    cmd = [sys.executable, "-m", "tumblebot.cli", "optimize", "--tasks", "nav-flat=1", "--xi", "3", "--trials", "400",
           "--batch", "4", "--startup", "1", "--workers", workers, "--storage", f"sqlite:///{db}", "--study", "m",
           "--quiet"]
    # interpreter start-up and imports (where a swallowed Ctrl-C once let a run carry on), study
    # creation, ask(), episodes, tell
    for delay in (0.05, 0.2, 0.4, 0.7, 1.0, 1.5, 2.0, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0, 7.5):
        existed = db.exists()
        run = _interrupt_at(cmd, delay)
        if run.returncode == -signal.SIGINT:
            # Ctrl-C while the interpreter was still starting, before any tumblebot code ran
            # (a loaded machine makes that window wide): Python's own exit, and nothing written.
            assert db.exists() == existed, f"Ctrl-C at {delay} s killed the process after it created the study"
            continue
        assert run.returncode in (130, 2), (delay, run.returncode, run.stderr[-2000:])
        assert "Traceback" not in run.stderr, (delay, run.stderr[-3000:])
        if db.exists():
            try:
                study = load(db, "m")
            except KeyError:
                continue  # stopped before the study was created
            running = [t.number for t in study.trials if t.state == optuna.trial.TrialState.RUNNING]
            assert running == [], f"Ctrl-C at {delay} s left trials {running} RUNNING"
    # and once more after a trial has been told, whenever that is on this machine
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            preexec_fn=interruptible)
    _wait_for_a_complete_trial(proc, db, "m")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    study = load(db, "m")
    assert counted_trials(study) >= 1
    assert all(t.state != optuna.trial.TrialState.RUNNING for t in study.trials)


# ------------------------------------------------------------------ scale-out
def _two_workers(storage: str, study: str, trials: int) -> list[subprocess.CompletedProcess[str]]:
    cmd = [sys.executable, "-m", "tumblebot.cli", "optimize", "--tasks", "nav-flat", "--xi", "3", "--trials",
           str(trials), "--batch", "2", "--startup", "4", "--storage", storage, "--study", study, "--quiet"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              stdin=subprocess.DEVNULL, env={**os.environ, "PYTHONWARNINGS": "ignore"})
             for _ in range(2)]
    return [subprocess.CompletedProcess(p.args, p.wait(timeout=600), *p.communicate()) for p in procs]


def _check_cooperation(study: optuna.Study, trials: int) -> None:
    counted = counted_trials(study)
    assert trials <= counted <= trials + 1  # a worker may start one trial just as the other finishes the last
    workers = {t.user_attrs.get("worker") for t in study.trials}
    assert len(workers) == 2, "both processes evaluated designs"
    params = [tuple(t.params.values()) for t in study.trials if t.number < 4]
    assert len(set(params)) == len(params), "start-up designs are not duplicated between workers"


@pytest.mark.slow
def test_that_two_worker_processes_cooperate_on_one_sqlite_study(tmp_path: Path) -> None:
    storage = f"sqlite:///{tmp_path / 'shared.db'}"
    for run in _two_workers(storage, "shared", 16):
        assert run.returncode == 0, run.stderr
    _check_cooperation(optuna.load_study(study_name="shared", storage=storage), 16)


@pytest.mark.slow
def test_that_two_worker_processes_cooperate_on_one_postgresql_study(postgres_url: str) -> None:
    for run in _two_workers(postgres_url, "shared-pg", 16):
        assert run.returncode == 0, run.stderr
    _check_cooperation(optuna.load_study(study_name="shared-pg", storage=postgres_url), 16)


@pytest.mark.slow
def test_that_the_report_checks_the_universal_optimum_across_tasks(tmp_path: Path) -> None:
    storage = f"sqlite:///{tmp_path / 'u.db'}"
    for task in ("nav-flat", "distance-flat"):
        tb_ok("optimize", "--tasks", task, "--xi", "0", "--trials", "4", "--batch", "2", "--storage", storage,
              "--study", task, "--quiet")
    out = tmp_path / "rep"
    tb_ok("report", "--storage", storage, "--study", "nav-flat", "--study", "distance-flat", "-o", str(out),
          "--episodes", "2", "--slice-points", "2", "--quiet")
    uni = json.loads((out / "report.json").read_text())["universal"]
    assert uni["checked"] and set(uni["matrix"]) == {"nav-flat", "distance-flat"}
    for task, row in uni["matrix"].items():  # each task's own optimum is the reference of its row
        assert row[task]["p_vs_own_optimum"] is None
        assert all(c["p_vs_own_optimum"] is not None for o, c in row.items() if o != task)
    assert "statistically the same robot" in (out / "report.md").read_text() or "not the same robot" in \
        (out / "report.md").read_text()


# ------------------------------------------------------------------ bad input, before any work
@pytest.mark.parametrize("command", [
    ["sim", "--task", "nav-flat"],
    ["evaluate", "--task", "nav-flat", "--design", "0.292,0.129,0.098,0.136", "--episodes", "1"],
    ["optimize", "--tasks", "nav-flat", "--xi", "3", "--trials", "2", "--batch", "2", "--study", "neg"],
    ["report", "--study", "neg", "-o", "rep"],
])
def test_that_a_negative_seed_is_one_error_line_and_creates_nothing(tmp_path: Path, command: list[str]) -> None:
    db = tmp_path / "neg.db"
    args = [*command, "--seed", "-1"]
    if command[0] in ("optimize", "report"):
        args += ["--storage", f"sqlite:///{db}"]
    run = subprocess.run([sys.executable, "-m", "tumblebot.cli", *args], capture_output=True, text=True, timeout=120,
                         check=False, stdin=subprocess.DEVNULL, cwd=tmp_path)
    assert run.returncode == 2 and "Traceback" not in run.stderr and "non-negative" in run.stderr, run.stderr
    assert not db.exists()


def test_that_outputs_that_cannot_be_written_are_refused_before_the_work(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    bad = blocker / "out"
    w = ["--design", "0.292,0.129,0.098,0.136"]
    for args in (["urdf", *w, "-o", str(bad / "r.urdf")],
                 ["sim", "--task", "nav-flat", *w, "--video", str(bad / "v.gif")],
                 ["evaluate", "--task", "nav-flat", *w, "--episodes", "1", "--csv", str(bad / "e.csv")],
                 ["demo", "--video-dir", str(bad)],
                 ["optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "2", "--storage",
                  f"sqlite:///{tmp_path / 'o.db'}", "--study", "o", "--json", str(bad / "o.json"), "--quiet"]):
        start = time.monotonic()
        run = tb(*args, timeout=120)
        assert run.returncode == 2 and "Traceback" not in run.stderr, (args, run.stderr)
        assert len([ln for ln in run.stderr.splitlines() if ln.startswith("tumblebot: error")]) == 1, run.stderr
        took = time.monotonic() - start  # a refusal takes seconds; the work behind it, minutes
        assert took < 60, f"{args[0]} took {took:.0f} s to refuse: it did the work first"
    assert not (tmp_path / "o.db").exists(), "optimize opened its study before checking --json"


def test_that_report_on_a_mistyped_sqlite_path_creates_no_database(tmp_path: Path) -> None:
    run = tb("report", "--storage", f"sqlite:///{tmp_path / 'typo.db'}", "--study", "s", "-o", str(tmp_path / "r"))
    assert run.returncode == 2 and "no database file" in run.stderr, run.stderr
    assert not (tmp_path / "typo.db").exists()


def test_that_xi_infinity_needs_no_batch(tmp_path: Path) -> None:
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "3", "--storage",
          f"sqlite:///{tmp_path / 'i.db'}", "--study", "i", "--quiet")


def test_that_evaluate_checks_xi_before_the_episodes(tmp_path: Path) -> None:
    run = tb("evaluate", "--task", "nav-flat", "--design", "0.292,0.129,0.098,0.136", "--xi", "-1",
             "--episodes", "100000")
    assert run.returncode == 2 and "--xi" in run.stderr, run.stderr


# ------------------------------------------------------------------ controller and servo of a study
def test_that_a_study_records_its_controller_and_servo_and_refuses_another(tmp_path: Path) -> None:
    storage = f"sqlite:///{tmp_path / 'g.db'}"
    base = ["optimize", "--tasks", "nav-flat", "--xi", "0", "--trials", "2", "--batch", "2", "--storage", storage,
            "--study", "g", "--quiet"]
    tb_ok(*base, "--gait", "goto", "--motor-model", "velocity", "--stall-torque", "10")
    config = load(tmp_path / "g.db", "g").user_attrs["tumblebot"]
    assert (config["controller"], config["motor_model"], config["stall_torque"]) == ("goto", "velocity", 10.0)
    for other in ([], ["--gait", "goto"], ["--gait", "goto", "--motor-model", "velocity"]):
        refused = tb(*base, *other)
        assert refused.returncode == 2 and "different objective" in refused.stderr, (other, refused.stderr)
    tb_ok("report", "--storage", storage, "--study", "g", "-o", str(tmp_path / "r"), "--episodes", "2",
          "--slice-points", "2", "--quiet")
    data = json.loads((tmp_path / "r" / "report.json").read_text())
    assert data["controller"] == "goto" and data["servo"]["motor_model"] == "velocity"
    assert data["servo"]["stall_torque"] == 10.0 and data["servo"]["free_speed"] == 3.67  # the whole profile
    assert len(data["servo"]["digest"]) == 16


def test_that_goto_is_refused_for_a_study_of_a_task_that_is_not_navigation(tmp_path: Path) -> None:
    run = tb("optimize", "--tasks", "incline", "--xi", "0", "--trials", "2", "--batch", "2", "--gait", "goto",
             "--storage", f"sqlite:///{tmp_path / 'n.db'}", "--study", "n", "--quiet")
    assert run.returncode == 2 and "not navigation" in run.stderr and not (tmp_path / "n.db").exists()


def test_that_a_study_made_before_controllers_were_recorded_still_loads_as_policy(tmp_path: Path) -> None:
    from tumblebot.sim.optimize import load_config

    storage = f"sqlite:///{tmp_path / 'old.db'}"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "2", "--storage", storage,
          "--study", "old", "--quiet")
    study = load(tmp_path / "old.db", "old")
    raw = dict(study.user_attrs["tumblebot"])
    for key in ("controller", "motor_model", "stall_torque", "front"):
        raw.pop(key)
    study.set_user_attr("tumblebot", raw)  # as a study of the last release stored it
    config = load_config(load(tmp_path / "old.db", "old"))
    assert config is not None and config.controller == "policy" and config.motor_model == "dc"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "3", "--storage", storage,
          "--study", "old", "--quiet")


def test_that_optimize_json_counts_the_trials_the_terminal_prints(tmp_path: Path) -> None:
    out = tmp_path / "s.json"
    run = tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "6", "--storage",
                f"sqlite:///{tmp_path / 'j.db'}", "--study", "j", "--json", str(out), "--quiet")
    printed = int(run.stdout.split(" trials in study")[0].split()[-1])
    summary = json.loads(out.read_text())
    assert summary["trials"] == printed == 6
    assert summary["feasible"] + summary["infeasible"] == 6


def test_that_optuna_dashboard_opens_a_study_from_the_same_storage_url(tmp_path: Path) -> None:
    from wsgiref.util import setup_testing_defaults

    from optuna_dashboard import wsgi

    storage = f"sqlite:///{tmp_path / 'dash.db'}"
    tb_ok("optimize", "--tasks", "nav-flat", "--xi", "inf", "--trials", "3", "--storage", storage,
          "--study", "dash", "--quiet")
    app = wsgi(storage)

    def get(path: str) -> dict:  # type: ignore[type-arg]
        environ: dict[str, object] = {}
        setup_testing_defaults(environ)
        environ.update(PATH_INFO=path, REQUEST_METHOD="GET")
        status: list[str] = []
        body = b"".join(app(environ, lambda s, h, exc=None: status.append(s)))
        assert status == ["200 OK"], (path, status, body[:200])
        return json.loads(body)  # type: ignore[no-any-return]

    summaries = get("/api/studies")["study_summaries"]
    assert [s["study_name"] for s in summaries] == ["dash"]
    detail = get(f"/api/studies/{summaries[0]['study_id']}")
    assert len(detail["trials"]) == 3


@pytest.mark.slow
def test_that_the_storage_password_never_appears_in_output_or_report_files(postgres_url: str, tmp_path: Path) -> None:
    """The lab's database password, given in the URL, is shown and stored as ``***``."""
    secret = "s3cret-Pa55"
    url = postgres_url.replace("tumblebot@", f"tumblebot:{secret}@")  # trust auth: the server ignores it
    run = tb_ok("optimize", "--tasks", "nav-flat", "--xi", "0", "--trials", "2", "--batch", "2", "--storage", url,
                "--study", "secret", "--gait", "goto", "--json", str(tmp_path / "summary.json"))
    assert "tumblebot:***@" in run.stdout + run.stderr
    out = tmp_path / "rep"
    rep = tb_ok("report", "--storage", url, "--study", "secret", "-o", str(out), "--episodes", "2", "--slice-points",
                "2", "--quiet")
    assert json.loads((out / "report.json").read_text())["storage"].startswith("postgresql://tumblebot:***@")
    refused = tb("optimize", "--tasks", "nav-flat", "--trials", "2", "--batch", "2", "--study", "x",
                 "--storage", f"postgresql://tumblebot:{secret}@127.0.0.1:1/none")  # nothing listens there
    assert refused.returncode == 2 and "cannot be opened" in refused.stderr
    written = [p.read_text(errors="replace") for p in tmp_path.rglob("*") if p.is_file() and p.suffix != ".png"]
    for text in (run.stdout, run.stderr, rep.stdout, rep.stderr, refused.stdout, refused.stderr, *written):
        assert secret not in text


def test_that_a_url_is_shown_without_its_password() -> None:
    from tumblebot.sim.optimize.storage import redact_url, scrub_password

    assert redact_url("postgresql://lab:hunter2@db:5432/tb") == "postgresql://lab:***@db:5432/tb"
    assert redact_url("postgresql://lab@db/tb?password=hunter2&sslmode=require") == \
        "postgresql://lab@db/tb?password=***&sslmode=require"
    assert redact_url("sqlite:///runs/demo.db") == "sqlite:///runs/demo.db"
    assert scrub_password("auth failed for p@ss", "postgresql://lab:p%40ss@db/tb") == "auth failed for ***"


def test_that_the_report_says_whether_the_thesis_optimum_is_still_the_robot_to_build(tmp_path: Path) -> None:
    """``report --physics P`` with a study optimised under ``thesis`` and one under ``P``:
    both optima scored under both worlds on the same episodes, and a one-line verdict."""
    storage = f"sqlite:///{tmp_path / 'r.db'}"
    lab = tmp_path / "lab.json"
    lab.write_text('{"name": "lab", "free_speed": 4.5, "stall_torque": 0.4, "friction": 0.6}')
    for study, extra in (("thesis-world", []), ("lab-world", ["--physics", str(lab)])):
        tb_ok("optimize", "--tasks", "nav-flat", "--xi", "0", "--trials", "4", "--batch", "2", "--gait", "goto",
              "--storage", storage, "--study", study, "--quiet", *extra)
    out = tmp_path / "rep"
    tb_ok("report", "--storage", storage, "--study", "thesis-world", "--study", "lab-world", "--physics", str(lab),
          "--gait", "goto", "-o", str(out), "--episodes", "4", "--slice-points", "2", "--quiet")
    data = json.loads((out / "report.json").read_text())
    [row] = data["rebuild"]
    assert row["thesis_study"] == "thesis-world" and row["physics_study"] == "lab-world"
    for world in ("physics", "thesis"):
        assert set(row[world]) == {"thesis_optimum", "physics_optimum", "p"}
    assert row["verdict"].startswith(("Yes:", "No:"))
    text = (out / "report.md").read_text()
    assert "## Would I still build it? (under `lab`)" in text and row["verdict"] in text
    # without a study of the profile's world, the section says what is missing
    tb_ok("report", "--storage", storage, "--study", "thesis-world", "--physics", str(lab), "--gait", "goto",
          "-o", str(tmp_path / "rep2"), "--episodes", "2", "--slice-points", "2", "--quiet")
    text = (tmp_path / "rep2" / "report.md").read_text()
    assert "Not answered: none of these studies was optimised under lab" in text


def test_that_a_worker_finishing_first_says_trials_are_still_running_regression_best_robot_trial_2(
        tmp_path: Path) -> None:
    """With two workers on one study, the first to finish printed "best robot: trial 2" while
    the real optimum was still running elsewhere, and nothing said so."""
    db = tmp_path / "s.db"
    args = ("optimize", "--tasks", "nav-flat", "--xi", "3", "--gait", "goto", "--trials", "4", "--batch", "4",
            "--recipe", "standard", "--storage", f"sqlite:///{db}", "--study", "s", "--seed", "0", "--quiet")
    first = tb_ok(*args)
    assert "still running" not in first.stdout and "best robot: trial" in first.stdout
    elsewhere = load(db, "s").ask()  # another worker's trial, still running
    again = tb_ok(*args)
    assert f"1 trial still running in other workers ({elsewhere.number})" in again.stdout
    assert "best robot so far: trial" in again.stdout


def test_that_the_printed_optimum_reproduces_its_e_regression_rounded_design_gave_another_e(tmp_path: Path) -> None:
    """optimize printed e = 3.591 for an optimum whose rounded numbers give 3.586 in power."""
    run = tb_ok("optimize", "--tasks", "nav-flat", "--xi", "3", "--gait", "goto", "--trials", "3", "--batch", "4",
                "--recipe", "standard", "--storage", f"sqlite:///{tmp_path / 'e.db'}", "--study", "e", "--seed", "0",
                "--quiet")
    printed_e = next(ln for ln in run.stdout.splitlines() if ln.strip().startswith("e(w) ="))
    exact = next(ln for ln in run.stdout.splitlines() if "exact design: tumblebot power" in ln)
    power = tb_ok("power", *exact.split("tumblebot power", 1)[1].split(), "--json")
    assert f"e(w) = {json.loads(power.stdout)['e']:.3f} W/m" in printed_e


# ------------------------------------------------------------------ pinned policies
def _policy_copy(tmp_path: Path, name: str, as_name: str) -> Path:
    """A copy of a bundled nav-flat policy (and its card) under another name."""
    import shutil

    from tumblebot.sim.control.policy import bundled_policy

    folder = bundled_policy("nav-flat").parent
    for suffix in (".onnx", ".json"):
        shutil.copy(folder / f"{name}{suffix}", tmp_path / f"{as_name}{suffix}")
    return tmp_path / f"{as_name}.onnx"


def test_that_a_study_pinned_to_a_policy_file_resumes_and_reports_only_with_that_file(tmp_path: Path) -> None:
    from tumblebot.sim.control.policy import sha256_of

    old = _policy_copy(tmp_path, "nav-flat-thesis", "old-nav-flat")  # a nav-flat policy other than the bundled one
    storage = f"sqlite:///{tmp_path / 'p.db'}"
    base = ["optimize", "--tasks", "nav-flat", "--xi", "3", "--trials", "2", "--batch", "2", "--storage", storage,
            "--study", "p", "--quiet"]
    tb_ok(*base, "--policy", f"nav-flat={old}")
    assert load(tmp_path / "p.db", "p").user_attrs["tumblebot"]["policies"] == {"nav-flat": sha256_of(old)}
    refused = tb(*base)  # the bundled policy is not the one the study ran with
    assert refused.returncode == 2 and "different objective" in refused.stderr, refused.stderr
    tb_ok(*base, "--trials", "3", "--policy", str(old))  # a bare FILE: the study's one task
    report = ["report", "--storage", storage, "--study", "p", "--episodes", "2", "--slice-points", "2", "--quiet"]
    stale = tb(*report, "-o", str(tmp_path / "stale"))
    err = stale.stderr.strip().splitlines()
    assert stale.returncode == 2 and len(err) == 1 and "--policy nav-flat=FILE" in err[0], stale.stderr
    assert not (tmp_path / "stale" / "report.md").exists()
    tb_ok(*report, "-o", str(tmp_path / "pinned"), "--policy", f"nav-flat={old}")
    data = json.loads((tmp_path / "pinned" / "report.json").read_text())
    assert data["policies"] == {"nav-flat": sha256_of(old)}
    tb_ok(*report, "-o", str(tmp_path / "goto"), "--gait", "goto")  # another controller: no pin


@pytest.mark.parametrize(("argv", "message"), [
    (["--policy", "missing.onnx"], "is not a file"),
    (["--policy", "incline=POLICY"], "not a task of nav-flat"),
    (["--policy", "nav-flat=POLICY", "--policy", "nav-flat=POLICY"], "two files for nav-flat"),
    (["--policy", "nav-flat=POLICY", "--gait", "goto"], "the controller here is 'goto'"),
    (["--policy", "warp=POLICY"], "unknown task 'warp'"),
])
def test_that_a_bad_policy_argument_is_one_error_line_and_writes_nothing(tmp_path: Path, argv: list[str],
                                                                          message: str) -> None:
    policy = _policy_copy(tmp_path, "nav-flat", "mine")
    argv = [a.replace("POLICY", str(policy)) for a in argv]
    run = tb("optimize", "--tasks", "nav-flat", "--xi", "3", "--trials", "2", "--batch", "2", "--storage",
             f"sqlite:///{tmp_path / 'x.db'}", "--quiet", *argv)
    err = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(err) == 1 and message in err[0], run.stderr
    assert not (tmp_path / "x.db").exists()
