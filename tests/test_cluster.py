"""Runs on a Ray cluster (`--ray ADDRESS`): the address rule, the archives that travel, and real runs on a
real local multi-node Ray cluster on 127.0.0.1 (tests/ray_local_cluster.py: a head and two worker nodes,
started here and stopped by their process id)."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cluster.address import check_address, is_loopback, split_address, token_configured
from gsgs_engine.cluster.worker import folder_files, pack, unpack

REPO = Path(__file__).resolve().parents[1]
LEGO = REPO.parent / "shared" / "data" / "lego_200"


# -- the address rule (no Ray needed) -------------------------------------------------------------
@pytest.mark.parametrize("address, host, port", [("127.0.0.1:6380", "127.0.0.1", 6380),
                                                 ("ray://localhost:10001", "localhost", 10001),
                                                 ("[::1]:6380", "::1", 6380), ("gpu-box", "gpu-box", None)])
def test_split_address(address, host, port):
    assert split_address(address)[1:] == (host, port)


@pytest.mark.parametrize("bad", ["", "http://x:1", "x:notaport", "x:70000", ":6380"])
def test_split_address_refuses_bad_input(bad):
    with pytest.raises(GsgsError):
        split_address(bad)


def test_loopback_needs_no_token_and_other_hosts_do(tmp_path):
    assert is_loopback("127.0.0.1") and is_loopback("127.3.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("10.1.2.3") and not is_loopback("192.0.2.7")
    no_token = {"HOME": str(tmp_path)}
    assert check_address("127.0.0.1:6380", no_token) == "127.0.0.1:6380"
    with pytest.raises(GsgsError, match="RAY_AUTH_MODE=token"):
        check_address("10.1.2.3:6380", no_token)
    with pytest.raises(GsgsError, match="no Ray token"):
        check_address("ray://10.1.2.3:10001", {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(tmp_path / "x")})
    token_file = tmp_path / "token"
    token_file.write_text("0123456789abcdef\n")
    assert token_configured({"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token_file)})
    assert check_address("10.1.2.3:6380", {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "abc"}) == "10.1.2.3:6380"
    assert not token_configured({"RAY_AUTH_TOKEN": "abc"})  # a token without token mode is not used by Ray


def test_non_loopback_address_is_refused_before_anything_is_read_or_sent(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH")}
    env.update(PYTHONPATH=str(REPO), HOME=str(tmp_path))
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "train", str(tmp_path / "no_such_scene"), "--out",
                           str(out), "--ray", "192.0.2.7:6380"], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert "192.0.2.7 is not this machine" in proc.stderr and "RAY_AUTH_MODE=token" in proc.stderr
    assert not out.exists()  # refused before the run folder (or the missing scene) was even looked at
    job = tmp_path / "job"
    from gsgs_engine.job import Job

    Job.create(job, "train", data={"path": str(LEGO)})
    proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "run-job", str(job), "--ray", "192.0.2.7:6380"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2 and "not this machine" in proc.stderr
    assert not (job / "status.json").exists()


class _FlakyRay:
    """Stands in for the `ray` module's init: the head's per-driver server dies `fails` times, then starts."""

    def __init__(self, fails: int, message: str = "Starting Ray client server failed. See x.err"):
        self.fails, self.message, self.calls = fails, message, 0

    def init(self, **_):
        self.calls += 1
        if self.calls <= self.fails:
            raise RuntimeError(f"Initialization failure from server:\n{self.message}")


def test_a_ray_client_server_that_dies_while_starting_is_retried(capsys):
    from gsgs_engine.cluster.remote import _init_with_client_retries

    flaky = _FlakyRay(fails=2)
    _init_with_client_retries(flaky, "ray://127.0.0.1:10001", None, attempts=3, wait_s=0)
    assert flaky.calls == 3 and capsys.readouterr().err.count("failed to start (attempt") == 2
    with pytest.raises(RuntimeError, match="client server failed"):  # the last attempt's failure is raised
        _init_with_client_retries(_FlakyRay(fails=3), "ray://127.0.0.1:10001", None, attempts=3, wait_s=0)
    other = _FlakyRay(fails=1, message="Connection refused")  # not a server start: no retry
    with pytest.raises(RuntimeError, match="refused"):
        _init_with_client_retries(other, "ray://127.0.0.1:10001", None, attempts=3, wait_s=0)
    assert other.calls == 1
    zombie = _FlakyRay(fails=1, message="psutil.ZombieProcess: PID still exists but it's a zombie (pid=29824)")
    _init_with_client_retries(zombie, "ray://127.0.0.1:10001", None, attempts=3, wait_s=0)  # the head's race
    assert zombie.calls == 2
    direct = _FlakyRay(fails=1)  # HOST:PORT (no Ray Client server) is not retried either
    with pytest.raises(RuntimeError):
        _init_with_client_retries(direct, "127.0.0.1:6380", None, attempts=3, wait_s=0)
    assert direct.calls == 1


def test_missing_ray_says_how_to_install(monkeypatch):
    from gsgs_engine.cluster import remote

    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` does where Ray is not installed
    with pytest.raises(GsgsError, match=r"pip install 'gsgs\[cluster\]'"):
        remote.import_ray()


# -- what travels ---------------------------------------------------------------------------------
def test_archives_round_trip_and_leave_out_temp_files(tmp_path):
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_0000010.safetensors").write_bytes(b"x" * 10)
    (tmp_path / "checkpoints" / ".ckpt.abc.tmp").write_bytes(b"half")
    (tmp_path / "cancel.request").touch()
    (tmp_path / "metrics.json").write_text("{}")
    assert set(folder_files(tmp_path)) == {"checkpoints/ckpt_0000010.safetensors", "metrics.json"}
    manifest, files = unpack(pack({"a": 1}, {"metrics.json": b"{}", "sub/b.bin": b"\0\1"}))
    assert manifest == {"a": 1} and files == {"metrics.json": b"{}", "sub/b.bin": b"\0\1"}


def _tar(member: tarfile.TarInfo, data: bytes = b"") -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        member.size = len(data) if member.isfile() else 0
        tar.addfile(member, io.BytesIO(data) if member.isfile() else None)
    return buf.getvalue()


@pytest.mark.parametrize("name, kind", [("data/../../etc/passwd", tarfile.REGTYPE), ("/data/x", tarfile.REGTYPE),
                                        ("data/link", tarfile.SYMTYPE), ("data/dev", tarfile.CHRTYPE),
                                        ("evil.py", tarfile.REGTYPE)])
def test_archives_from_another_machine_are_checked(name, kind):
    member = tarfile.TarInfo(name)
    member.type = kind
    member.linkname = "/etc/passwd" if kind == tarfile.SYMTYPE else ""
    with pytest.raises(ValueError):
        unpack(_tar(member, b"x"))


def test_job_paths_send_what_the_job_names_from_outside_its_folder(tmp_path):
    from gsgs_engine.cluster.submit import job_paths

    scene, photo, job = tmp_path / "scene", tmp_path / "photos" / "a.png", tmp_path / "job"
    scene.mkdir()
    photo.parent.mkdir()
    photo.write_bytes(b"png")
    job.mkdir()
    (job / "points.ply").write_bytes(b"ply")
    spec = {"data": {"path": str(scene), "points": "points.ply",
                     "cameras": [{"image": str(photo)}, {"image": str(photo)}]}}
    rewritten, sends = job_paths(spec, job)
    assert rewritten["data"]["path"] == "../in_path" and sends["in_path"] == scene.resolve()
    assert rewritten["data"]["points"] == "points.ply"  # inside the job folder: travels with it
    images = [c["image"] for c in rewritten["data"]["cameras"]]
    assert images == ["../in_files/0000_a.png", "../in_files/0001_a.png"]
    assert spec["data"]["path"] == str(scene)  # the local job.json is not changed
    with pytest.raises(GsgsError, match="not a folder"):
        job_paths({"data": {"path": str(tmp_path / "nowhere")}}, job)


# -- a real local cluster -------------------------------------------------------------------------
def ray_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH")}
    env.update(RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", **extra)
    return env


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    pytest.importorskip("ray", reason="Ray is not installed (make test installs the [cluster] extra)")
    temp = tmp_path_factory.mktemp("ray")
    log = open(temp / "cluster.log", "w")
    import socket

    with socket.socket() as s:  # a free port for the Ray Client server (ray://)
        s.bind(("127.0.0.1", 0))
        client_port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, str(REPO / "tests" / "ray_local_cluster.py"), "--workers", "2",
                             "--cpus", "1", "--temp-dir", str(temp / "r"), "--client-port", str(client_port)],
                            stdout=subprocess.PIPE, stderr=log,
                            text=True, env=ray_env())
    try:
        line = proc.stdout.readline()
        if not line:
            pytest.fail(f"the local Ray cluster did not start: {(temp / 'cluster.log').read_text()[-2000:]}")
        info = json.loads(line)
        assert info["address"].startswith("127.0.0.1:"), info  # nothing on the machine's network address
        info["logs"] = temp / "r" / "session_latest" / "logs"
        yield info
    finally:
        proc.send_signal(signal.SIGTERM)  # the harness shuts down every process of the cluster
        try:
            proc.wait(timeout=90)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        for node in info.get("nodes", []) if "info" in locals() else []:
            for pid in node["pids"]:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        log.close()


def gsgs(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gsgs_engine", *map(str, args)], capture_output=True, text=True,
                          env=ray_env(), timeout=kw.pop("timeout", 600), **kw)


needs_lego = pytest.mark.skipif(not LEGO.is_dir(), reason=f"{LEGO} absent (../shared/data)")


@pytest.mark.slow
@needs_lego
def test_train_on_the_cluster_equals_the_local_run(ray_cluster, tmp_path):
    common = [LEGO, "--iters", 60, "--prior", "none", "--seed", 0]
    local = gsgs("train", *common, "--out", tmp_path / "local")
    assert local.returncode == 0, local.stderr[-2000:]
    remote = gsgs("train", *common, "--ray", ray_cluster["address"], "--out", tmp_path / "remote")
    assert remote.returncode == 0, remote.stderr[-3000:]
    assert "node 127.0.0.1" in remote.stderr  # the worker ran on a loopback node
    assert f"results in {tmp_path / 'remote'}" in remote.stderr  # the engine's message names the local folder
    assert (tmp_path / "local" / "point_cloud.ply").read_bytes() == (tmp_path / "remote" / "point_cloud.ply").read_bytes()
    a = json.loads((tmp_path / "local" / "metrics.json").read_text())
    b = json.loads((tmp_path / "remote" / "metrics.json").read_text())
    assert a["psnr"] == b["psnr"] and a["num_gaussians"] == b["num_gaussians"]
    assert b["plan"]["data"] == str(LEGO)  # the user's path, not the worker's copy
    status = json.loads((tmp_path / "remote" / "status.json").read_text())
    assert status["state"] == "ok" and status["pid"] != status["remote"]["pid"]
    events = [json.loads(line) for line in (tmp_path / "remote" / "progress.jsonl").read_text().splitlines()]
    assert events[-1]["phase"] in ("done", "eval", "export") or events[-1]["step"] == events[-1]["total"]
    assert sorted(p.name for p in (tmp_path / "remote" / "renders").iterdir()) == \
        sorted(p.name for p in (tmp_path / "local" / "renders").iterdir())
    client = gsgs("train", *common, "--ray", ray_cluster["client_address"], "--out", tmp_path / "client")
    assert client.returncode == 0, client.stderr[-3000:] + _client_server_logs(ray_cluster["logs"])  # ray:// too
    assert (tmp_path / "client" / "point_cloud.ply").read_bytes() == (tmp_path / "local" / "point_cloud.ply").read_bytes()


def _client_server_logs(logs: Path) -> str:
    """The head's per-driver Ray Client server logs, for a failure message."""
    return "".join(f"\n--- {p.name}:\n{p.read_text(errors='replace')[-1500:]}"
                   for p in sorted(logs.glob("ray_client_server*.err")) + sorted(logs.glob("ray_client_server_*.out")))


def _wait_for(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.5)


def _training_step(out: Path) -> int:
    from gsgs_engine.job import ProgressReader

    events = [e for e in ProgressReader(out).poll() if e.get("phase") == "train"]
    return events[-1]["step"] if events else -1


def _parent_pid(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


@pytest.mark.slow
@needs_lego
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the Ray worker process through /proc")
def test_a_killed_worker_is_retried_from_its_last_checkpoint(ray_cluster, tmp_path):
    common = [LEGO, "--iters", 300, "--checkpoint-every", 100, "--prior", "none", "--seed", 0]
    out = tmp_path / "remote"
    with open(tmp_path / "driver.log", "w") as log:
        driver = subprocess.Popen([sys.executable, "-m", "gsgs_engine", "train", *map(str, common), "--ray",
                                   ray_cluster["address"], "--out", str(out)], stdout=log, stderr=log, env=ray_env())
        try:
            _wait_for(lambda: (out / "checkpoints" / "ckpt_0000100.safetensors").is_file(), 300, "a checkpoint")
            engine = json.loads((out / "status.json").read_text())["remote"]["pid"]
            os.kill(_parent_pid(engine), signal.SIGKILL)  # the Ray worker process hosting the run
            assert driver.wait(timeout=600) == 0
        finally:
            if driver.poll() is None:
                driver.kill()
    text = (tmp_path / "driver.log").read_text()
    assert "lost the Ray worker" in text and "from the last checkpoint" in text, text[-3000:]
    assert "resuming from" in (out / "log.txt").read_text()
    local = gsgs("train", *common, "--out", tmp_path / "local")
    assert local.returncode == 0, local.stderr[-2000:]
    # resume is bit-exact: the interrupted run equals the uninterrupted one byte for byte
    assert (out / "point_cloud.ply").read_bytes() == (tmp_path / "local" / "point_cloud.ply").read_bytes()


@pytest.mark.slow
@needs_lego
def test_cancel_from_the_cli_stops_the_remote_run(ray_cluster, tmp_path):
    out = tmp_path / "remote"
    with open(tmp_path / "driver.log", "w") as log:
        driver = subprocess.Popen([sys.executable, "-m", "gsgs_engine", "train", str(LEGO), "--iters", "5000",
                                   "--prior", "none", "--ray", ray_cluster["address"], "--out", str(out)],
                                  stdout=log, stderr=log, env=ray_env())
        try:
            _wait_for(lambda: _training_step(out) >= 2, 300, "training steps")
            engine = json.loads((out / "status.json").read_text())["remote"]["pid"]
            driver.send_signal(signal.SIGTERM)  # what Ctrl-C or the add-on's Cancel does to the driver
            assert driver.wait(timeout=180) in (130, 143)  # as a local run: 128 + SIGTERM once training
        finally:
            if driver.poll() is None:
                driver.kill()
    status = json.loads((out / "status.json").read_text())
    assert status["state"] == "cancelled" and "--resume" in status["message"], status
    assert "/gsgs_remote_" not in status["message"]  # the resume command is the local one
    _wait_for(lambda: not Path(f"/proc/{engine}").exists(), 30, "the remote engine to exit")
    assert list((out / "checkpoints").glob("ckpt_*.safetensors"))  # the checkpoint it saved came back


@pytest.mark.slow
@needs_lego
def test_resume_on_the_cluster_continues_a_local_run(ray_cluster, tmp_path):
    out = tmp_path / "run"
    args = [LEGO, "--iters", 300, "--prior", "none", "--checkpoint-every", 50, "--seed", 0, "--out", out]
    local = subprocess.Popen([sys.executable, "-m", "gsgs_engine", "train", *map(str, args)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ray_env())
    try:
        _wait_for(lambda: (out / "checkpoints" / "ckpt_0000050.safetensors").is_file(), 300, "a local checkpoint")
        local.send_signal(signal.SIGTERM)  # stopped here (a checkpoint is saved), continued on the cluster
        local.wait(timeout=120)
    finally:
        if local.poll() is None:
            local.kill()
    assert json.loads((out / "status.json").read_text())["state"] == "cancelled"
    more = gsgs("train", *args, "--resume", "--ray", ray_cluster["address"])
    assert more.returncode == 0, more.stderr[-3000:]
    assert "resuming from" in more.stderr
    assert json.loads((out / "metrics.json").read_text())["iterations"] == 300
    whole = gsgs("train", *args[:-1], tmp_path / "whole")
    assert whole.returncode == 0, whole.stderr[-2000:]
    assert (out / "point_cloud.ply").read_bytes() == (tmp_path / "whole" / "point_cloud.ply").read_bytes()


BLENDER_LEGO = REPO.parent / "shared" / "data" / "blender_lego"


@pytest.mark.slow
@pytest.mark.skipif(not BLENDER_LEGO.is_dir(), reason=f"{BLENDER_LEGO} absent (../shared/data)")
def test_a_grid_on_the_cluster_equals_the_local_grid(ray_cluster, tmp_path):
    """4 cells (2 variants x 2 seeds) on the 2-worker cluster and one after another here: the same numbers.
    (The wall-time ratio of the two is measured in docs/cluster.md, not asserted: timings here are noisy.)"""
    grid = ["bench", "sparse", "--protocol", "blender", "--scene", "blender_lego", "--seeds", 2, "--iters", 20,
            "--resolution-scale", 0.125, "--variants", json.dumps({"plain": {"prior": "none"},
                                                                    "sh1": {"prior": "none", "sh_degree": 1}}),
            "--data-root", BLENDER_LEGO.parent]
    runs = {}
    for name, extra in (("local", []), ("cluster", ["--ray", ray_cluster["address"]])):
        proc = gsgs(*grid, "--work", tmp_path / name, "--doc", tmp_path / f"{name}.md", *extra)
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[name] = json.loads((tmp_path / f"{name}.json").read_text())
    cells = {name: {(c["variant"], c["seed"]): c["metrics"] for c in run["cells"]} for name, run in runs.items()}
    assert len(cells["local"]) == 4 and cells["local"].keys() == cells["cluster"].keys()
    for key, local in cells["local"].items():
        remote = cells["cluster"][key]
        for field in ("psnr", "ssim", "lpips_vgg", "num_gaussians"):
            assert local[field] == remote[field], (key, field, local[field], remote[field])
    assert runs["cluster"]["meta"]["machine"].startswith("Ray cluster at 127.0.0.1:")
    again = gsgs(*grid, "--work", tmp_path / "cluster", "--doc", tmp_path / "again.md", "--ray", ray_cluster["address"])
    assert again.stdout.count("done before, skipped") + again.stderr.count("done before, skipped") == 4


# -- the add-on (the real bpy module): "Run jobs on: Ray cluster" ------------------------------------------
class _ClusterPrefs:
    run_on, ray_token, ray_cpus, device = "ray", "", 1, "cpu"

    def __init__(self, address: str):
        self.ray_address = address


def test_addon_refuses_a_remote_cluster_without_a_token(monkeypatch):
    pytest.importorskip("bpy", reason="the add-on needs the bpy module")
    from gsgs_blender import ops_common

    for key in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("HOME", "/nonexistent")
    with pytest.raises(GsgsError, match="not this machine"):
        ops_common.cluster_launch(_ClusterPrefs("192.0.2.7:6380"))
    prefs = _ClusterPrefs("192.0.2.7:6380")
    prefs.ray_token = "s3cret"
    args, env, grace = ops_common.cluster_launch(prefs)
    assert args[:2] == ["--ray", "192.0.2.7:6380"] and env == {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "s3cret"}
    assert ops_common.cluster_launch(type("Local", (), {"run_on": "local"})()) == ([], {}, None)


@pytest.mark.slow
@needs_lego
def test_addon_cluster_job_cancels_resumes_and_reattaches(ray_cluster, tmp_path, monkeypatch):
    pytest.importorskip("bpy", reason="the add-on needs the bpy module")
    from gsgs_blender import job_runner, ops_common
    from gsgs_engine.io.ply import read_ply_vertices
    from gsgs_engine.job import Job

    for key, value in ray_env().items():
        monkeypatch.setenv(key, value)
    args, env, grace = ops_common.cluster_launch(_ClusterPrefs(ray_cluster["address"]))
    job = Job.create(tmp_path / "job", "train", data={"path": str(LEGO)},
                     settings={"iters": 800, "prior": "none", "checkpoint_every": 100, "seed": 0})

    def start():
        return job_runner.start(job.root, sys.executable, engine_root=REPO, use_timer=False, extra_args=args,
                                extra_env=env, cancel_grace_s=grace)

    try:
        run = start()
        _wait_for(lambda: run.poll() is not None and (run.last_event or {}).get("phase") == "train"
                  and run.last_event["step"] >= 2, 300, "training on the cluster")
        engine = json.loads((job.root / "status.json").read_text())["remote"]["pid"]
        run.request_cancel()  # the panel's Cancel
        assert run.wait(timeout=200) == "cancelled", run.message
        assert job.status()["state"] == "cancelled"
        _wait_for(lambda: not Path(f"/proc/{engine}").exists(), 30, "the remote engine to exit")
        assert list((job.root / "checkpoints").glob("ckpt_*.safetensors"))

        run = start()  # Resume: the job continues on the cluster from the checkpoint that came back
        _wait_for(lambda: run.poll() is not None and run.events > 0, 300, "the resumed job's progress")
        job_runner.RUNS.clear()  # a reopened .blend: this session knows the job only by its folder
        again = job_runner.attach(job.root)
        assert again.state == "running" and again.process is None
        assert again.wait(timeout=600) == "ok", again.message
    finally:
        for r in list(job_runner.RUNS.values()) + ([run] if "run" in locals() else []):
            if r.process is not None and r.process.poll() is None:
                r.process.terminate()
                r.process.wait(timeout=120)
        job_runner.RUNS.clear()
    log = (job.root / "log.txt").read_text()
    # the engine's log lines came back appended beside what the add-on and the driver wrote, none overwritten
    assert "resuming from" in log and log.count("== gsgs: starting") == 2 and "running on the Ray cluster" in log
    metrics = json.loads((job.root / "result" / "metrics.json").read_text())
    assert metrics["iterations"] == 800
    assert len(read_ply_vertices(job.root / "result" / "point_cloud.ply")["x"]) == metrics["num_gaussians"]


@pytest.mark.slow
@needs_lego
def test_accuracy_cells_on_the_cluster_equal_local_cells(ray_cluster, tmp_path):
    grid = tmp_path / "grid.json"
    grid.write_text(json.dumps([{"iters": 20, "prior": "none", "backend": "cpu"},
                                {"iters": 40, "prior": "none", "backend": "cpu"}]))
    records = {}
    for name, extra in (("local", []), ("cluster", ["--ray", ray_cluster["address"]])):
        proc = gsgs("bench", "accuracy", LEGO, "--out", tmp_path / name, "--grid", grid, *extra)
        assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
        lines = (tmp_path / name / "results.jsonl").read_text().splitlines()
        records[name] = {r["id"]: r for r in map(json.loads, lines)}
    assert len(records["local"]) == 2 and records["local"].keys() == records["cluster"].keys()
    for key, local in records["local"].items():
        remote = records["cluster"][key]
        assert remote["status"] == "ok" and remote["ran_on"].startswith("Ray cluster at 127.0.0.1:")
        assert (local["psnr"], local["ssim"], local["num_gaussians"]) == \
            (remote["psnr"], remote["ssim"], remote["num_gaussians"])
        assert remote["peak_memory_mb"] > 50  # the worker's engine process, not this driver
    assert (tmp_path / "cluster" / "accuracy_lego_200.md").is_file()


SANTORINI = REPO.parent / "shared" / "data" / "photos_santorini"


@pytest.mark.slow
@pytest.mark.skipif(not SANTORINI.is_dir(), reason=f"{SANTORINI} absent (../shared/data)")
def test_an_sfm_job_on_the_cluster_names_the_local_photos(ray_cluster, tmp_path):
    from gsgs_engine.job import Job

    job = Job.create(tmp_path / "sfm", "sfm", data={"photos": str(SANTORINI)}, settings={"max_image_size": 480})
    proc = gsgs("run-job", job.root, "--ray", ray_cluster["address"])
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert job.status()["state"] == "ok", job.status()
    cameras = json.loads((job.root / "result" / "cameras.json").read_text())
    assert len(cameras) >= 2
    for entry in cameras:  # the worker's copies are gone; the add-on shows the photos it has here
        assert Path(entry["image"]).is_file(), entry["image"]
        assert "gsgs_remote_" not in entry["image"]
    assert json.loads((job.root / "job.json").read_text())["data"]["photos"] == str(SANTORINI)  # not rewritten here


def test_a_worker_without_gsgs_or_with_another_version_is_one_clear_error():
    from gsgs_engine import __version__
    from gsgs_engine.cluster.remote import check_worker

    check_worker({"version": __version__, "host": "n1"})
    with pytest.raises(GsgsError, match=r"runs gsgs 0\.0\.1, this machine gsgs"):
        check_worker({"version": "0.0.1", "host": "n1"})
    with pytest.raises(GsgsError, match="has no gsgs engine.*GSGS_RAY_RUNTIME_ENV"):
        check_worker({"version": None, "host": "n1", "python": "/usr/bin/python3",
                      "import_error": "ModuleNotFoundError: No module named 'gsgs_engine'"})


def test_the_worker_actor_needs_only_the_standard_library():
    """It is sent by value and must start where gsgs is not installed (to say so)."""
    code = ("import sys, importlib.util; spec = importlib.util.spec_from_file_location('w', sys.argv[1]); "
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); r = m.EngineRun(); "
            "print(m.unpack(r.hello())[0]['version'])")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-I", "-S", "-c", code, str(REPO / "gsgs_engine" / "cluster" / "worker.py")],
                          capture_output=True, text=True, env=env, cwd="/", timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "None"  # -S: no site-packages, so no gsgs: reported, not raised
