# torch.profiler over steps A..B of `gsgs run-job JOB` (cf100e1 in session 28): python prof.py A B JOB_FOLDER
# torch.profiler over steps A..B of `gsgs run-job JOB`: python prof.py A B JOB
import runpy, sys, os, time
if __name__ == "__main__":
    import torch
    from torch.profiler import profile, ProfilerActivity
    from gsgs_engine.train import trainer
    A, B = int(sys.argv[1]), int(sys.argv[2])
    orig = trainer.Trainer.train_step
    st = {}
    def ts(self):
        if self.step == A:
            st['p'] = profile(activities=[ProfilerActivity.CPU]); st['p'].__enter__(); st['t'] = time.perf_counter()
        r = orig(self)
        if self.step == B:
            dt = time.perf_counter() - st['t']
            st['p'].__exit__(None, None, None)
            print(f"steps {A}-{B}: {dt:.2f} s, {1000*dt/(B-A):.1f} ms/step, gaussians {self.model.num_gaussians}")
            print(st['p'].key_averages().table(sort_by="self_cpu_time_total", row_limit=45, max_name_column_width=60))
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    job = sys.argv[3]
    sys.argv = ['gsgs', 'run-job', job]
    runpy.run_module('gsgs_engine', run_name='__main__')
