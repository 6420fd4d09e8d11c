"""`gsgs run-job JOB_DIR`: run the task a job folder describes, reporting through the folder."""

from __future__ import annotations

import argparse
import traceback

from gsgs_engine import GsgsError
from gsgs_engine.job import Job


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job_dir", help="job folder containing job.json")
    from gsgs_engine.cluster.submit import add_ray_arguments

    add_ray_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "ray", None):
        from gsgs_engine.cluster.address import check_address
        from gsgs_engine.cluster.submit import job_on_cluster, resources

        check_address(args.ray)
        Job.open(args.job_dir)
        cpus, gpus = resources(args, None)
        return job_on_cluster(args.job_dir, args.ray, cpus, gpus, args.ray_retries)
    job = Job.open(args.job_dir)
    job.set_status("running", f"{job.task} started")
    try:
        if job.task == "sfm":
            from gsgs_engine.sfm import run_sfm_job
            run_sfm_job(job)
        else:  # train and validate both train; validate also evaluates on held-out views
            from gsgs_engine.reconstruct import run_train_job
            run_train_job(job)
    except GsgsError as exc:
        job.set_status("error", str(exc))
        raise
    except KeyboardInterrupt:
        job.set_status("cancelled", "cancelled; resume continues from the last checkpoint")
        return 130
    except Exception as exc:
        with open(job.log_path, "a") as fh:
            fh.write(traceback.format_exc())
        job.set_status("error", f"{type(exc).__name__}: {exc} (see {job.log_path})")
        raise
    status = job.status() or {}
    if status.get("state") == "running":
        job.set_status("ok", f"{job.task} finished")
    return 0
