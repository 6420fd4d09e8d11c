# torch.profiler over steps A..B of `gsgs run-job JOB` (session 31): python step_profile.py A B JOB_FOLDER
import runpy, sys, os
if __name__ == "__main__":
    import torch
    from torch.profiler import profile, ProfilerActivity
    from gsgs_engine.train import trainer
    A, B = int(sys.argv[1]), int(sys.argv[2]); st = {}
    orig = trainer.Trainer.train_step
    def ts(self):
        if self.step == A:
            st['p'] = profile(activities=[ProfilerActivity.CPU]); st['p'].__enter__()
        r = orig(self)
        if self.step == B:
            p = st['p']; p.__exit__(None, None, None)
            print(p.key_averages().table(sort_by="self_cpu_time_total", row_limit=45), flush=True)
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    sys.argv = ['gsgs', 'run-job', sys.argv[3]]
    runpy.run_module('gsgs_engine', run_name='__main__')
