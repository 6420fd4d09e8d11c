"""Background jobs with real child processes: progress, cancel, resume and errors reach the add-on."""

from __future__ import annotations

import sys
import time

import pytest

from gsgs_blender import job_runner
from gsgs_engine import GsgsError
from gsgs_engine.job import Job

from conftest import REPO, shared_scene

# A stand-in engine with the same folder protocol, so runner behaviour is tested quickly and
# deterministically; the real engine runs in the slow tests below.
FAKE_ENGINE = r'''
import sys, time
from gsgs_engine.job import Job
job = Job.open(sys.argv[1])
job.set_status("running", "started")
mode = job.spec["settings"].get("mode", "ok")
n = job.spec["settings"].get("steps", 10)
for i in range(n):
    if mode != "ignore_cancel" and job.cancel_requested():
        job.set_status("cancelled", f"stopped at step {i}")
        sys.exit(0)
    job.emit("train", i + 1, n, losses={"l1": 1.0 / (i + 1)}, eta_s=(n - i) * 0.02)
    time.sleep(0.02)
if mode == "crash":
    print("boom: something broke", flush=True)
    sys.exit(3)
job.set_status("ok", "done")
'''


@pytest.fixture()
def fake(tmp_path):
    script = tmp_path / "fake_engine.py"
    script.write_text(FAKE_ENGINE)

    def make(mode="ok", steps=10, name="job"):
        job = Job.create(tmp_path / name, "train", data={"path": "none"}, settings={"mode": mode, "steps": steps})
        return job.root, [sys.executable, str(script), str(job.root)]

    yield make
    for run in list(job_runner.RUNS.values()):  # never leave a child behind
        if run.process is not None and run.process.poll() is None:
            run.process.kill()
            run.process.wait()
    job_runner.RUNS.clear()


def _start(job_dir, command, **kw):
    return job_runner.start(job_dir, sys.executable, engine_root=REPO, command=command, use_timer=False, **kw)


def test_progress_is_seen_and_ok_reported(fake):
    job_dir, cmd = fake("ok", steps=8)
    finished = []
    run = _start(job_dir, cmd, on_finish=finished.append)
    assert job_runner.wait_for(run, timeout=60, echo=False) == "ok"
    assert run.events == 8 and run.progress == 1.0
    assert run.summary()["losses"].startswith("l1 0.125")
    assert finished == [run]  # the callback fires exactly once
    job_runner.tick_all()
    assert finished == [run]
    assert "== gsgs: starting" in (job_dir / "log.txt").read_text()


def test_cancel_request_is_honoured(fake):
    job_dir, cmd = fake("ok", steps=10_000)
    run = _start(job_dir, cmd)
    deadline = time.monotonic() + 30
    while run.events == 0 and time.monotonic() < deadline:
        run.poll()
        time.sleep(0.05)
    assert run.events > 0, "no progress event arrived"
    run.request_cancel()
    assert run.wait(timeout=30) == "cancelled"
    assert run.message.startswith("stopped at step")
    assert run.process.returncode == 0


def test_cancel_terminates_after_grace_when_ignored(fake, monkeypatch):
    monkeypatch.setattr(job_runner, "CANCEL_GRACE_S", 0.3)
    job_dir, cmd = fake("ignore_cancel", steps=10_000)
    run = _start(job_dir, cmd)
    run.request_cancel()
    assert run.wait(timeout=30) == "cancelled"
    assert "grace period" in run.message
    assert Job.open(job_dir).status()["state"] == "cancelled"
    assert run.process.returncode != 0


def test_crash_without_status_reports_log_tail(fake):
    job_dir, cmd = fake("crash", steps=2)
    run = _start(job_dir, cmd)
    assert run.wait(timeout=30) == "error"
    assert "code 3" in run.message and "boom: something broke" in run.message
    assert Job.open(job_dir).status()["state"] == "error"


def test_resume_runs_again_and_shows_only_new_events(fake):
    job_dir, cmd = fake("ok", steps=10_000)
    run = _start(job_dir, cmd)
    run.request_cancel()
    assert run.wait(timeout=30) == "cancelled"
    job = Job.open(job_dir)
    job.spec["settings"]["steps"] = 3
    Job.create(job_dir, "train", data=job.spec["data"], settings=job.spec["settings"])
    with pytest.raises(GsgsError, match="already running"):
        job_runner.RUNS[str(job_dir.resolve())].state = "running"
        _start(job_dir, cmd)
    job_runner.RUNS[str(job_dir.resolve())].state = "cancelled"
    again = _start(job_dir, cmd)
    assert again.wait(timeout=30) == "ok"
    assert again.events == 3 and not (job_dir / "cancel.request").exists()


def test_bad_interpreter_is_a_clear_error(tmp_path):
    job = Job.create(tmp_path / "j", "train", data={"path": "x"})
    with pytest.raises(GsgsError, match="engine interpreter"):
        job_runner.start(job.root, str(tmp_path / "no-python"), use_timer=False)


def test_attach_reads_a_finished_folder(fake):
    job_dir, cmd = fake("ok", steps=2)
    run = _start(job_dir, cmd)
    run.wait(timeout=30)
    job_runner.RUNS.clear()
    view = job_runner.attach(job_dir)
    assert view.state == "ok" and view.last_event["step"] == 2 and view.process is None


def test_formatting():
    assert job_runner.format_eta(3725) == "1:02:05" and job_runner.format_eta(65) == "1:05"
    assert job_runner.format_eta(None) == ""
    assert job_runner.format_losses({"psnr": 23.456789, "phase": "x"}) == "psnr 23.46, phase x"


# -- the real engine ----------------------------------------------------------------------------

@pytest.mark.slow
def test_real_engine_failing_job_reports_its_error(tmp_path):
    missing = tmp_path / "no_such_scene"
    job = Job.create(tmp_path / "job", "train", data={"path": str(missing), "format": "auto"},
                     settings={"iters": 10})
    run = job_runner.start(job.root, sys.executable, engine_root=REPO, use_timer=False)
    assert run.wait(timeout=120) == "error"
    assert run.process.returncode != 0
    assert "no_such_scene" in run.message, run.message


@pytest.mark.slow
def test_real_sfm_job_progress_and_cancel(tmp_path):
    photos = shared_scene("photos_santorini")
    job = Job.create(tmp_path / "sfm", "sfm", data={"photos": str(photos)},
                     settings={"max_image_size": 480})
    run = job_runner.start(job.root, sys.executable, engine_root=REPO, use_timer=False)
    deadline = time.monotonic() + 120
    while run.events == 0 and not run.finished and time.monotonic() < deadline:
        run.poll()
        time.sleep(0.1)
    assert run.events > 0, job_runner.log_tail(job.root)
    assert not run.finished, f"SfM finished before the cancel could be tested: {run.message}"
    run.request_cancel()
    t0 = time.monotonic()
    assert run.wait(timeout=120) == "cancelled", run.message
    print(f"\nSfM cancelled {time.monotonic() - t0:.1f} s after the request: {run.message}")
    assert Job.open(job.root).status()["state"] == "cancelled"
    assert not (job.root / "result" / "cameras.json").exists()


def test_wait_timeout_cancels_the_job(fake):
    job_dir, cmd = fake("ok", steps=10_000)
    run = _start(job_dir, cmd)
    with pytest.raises(GsgsError, match="still running after 0 s, so it was cancelled"):
        run.wait(timeout=0.3)
    assert run.process.poll() is not None
