"""The progress reporter's time-left estimate: the pace after the first step, not the first step's one-off work."""

from __future__ import annotations

import io

from gsgs_engine.progress import Progress, format_seconds


class Clock:
    """A clock the test moves by hand (seconds)."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_eta_leaves_out_the_first_steps_one_off_work():
    # the shape of a first GPU run: step 1 waits 81 s for gsplat's kernel build, the other steps take 0.02 s
    clock, out = Clock(), io.StringIO()
    p = Progress("train", 1000, stream=out, clock=clock)
    clock.now += 81.0
    p.update(1)
    assert p.eta(1) is None  # one step says nothing about the pace yet
    for step in range(2, 101):
        clock.now += 0.02
        p.update(step)
    assert abs(p.eta(100) - 900 * 0.02) < 1e-6  # 18 s left, not the 12 minutes the mean since the start gives
    assert "eta 00:18" in out.getvalue().splitlines()[-1]
    assert "elapsed 01:23" in out.getvalue().splitlines()[-1]  # elapsed still counts the first step


def test_eta_of_a_resumed_run_counts_from_its_first_step_after_the_resume():
    clock = Clock()
    p = Progress("train", 100, stream=io.StringIO(), start_step=40, clock=clock)
    assert p.eta(40) is None
    clock.now += 5.0
    p.update(41)
    clock.now += 1.0
    p.update(51)
    assert abs(p.eta(51) - 49 * 0.1) < 1e-9
    clock.now += 4.9
    p.update(100)
    assert p.eta(100) == 0.0


def test_job_events_carry_the_estimate(tmp_path):
    """What the add-on's panel reads (progress.jsonl's eta_s): nothing after the first step, then the later pace."""
    import json

    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "job", "train")
    clock = Clock()
    p = Progress("train", 200, job=job, stream=io.StringIO(), emit_interval_s=0.0, clock=clock)
    clock.now += 60.0
    p.update(1)
    for step in range(2, 11):
        clock.now += 0.5
        p.update(step)
    events = [json.loads(line) for line in job.progress_path.read_text().splitlines()]
    assert [e["step"] for e in events] == list(range(1, 11))
    assert events[0]["eta_s"] is None
    assert abs(events[-1]["eta_s"] - 190 * 0.5) < 1e-6
    assert format_seconds(events[-1]["eta_s"]) == "01:35"
