# torch.profiler over steps A..B of `gsgs run-job JOB`, grouped by Python stack (session 34)
import runpy, sys, os
if __name__ == "__main__":
    import torch
    from torch.profiler import profile, ProfilerActivity
    from gsgs_engine.train import trainer
    A, B = int(sys.argv[1]), int(sys.argv[2]); st = {}
    orig = trainer.Trainer.train_step
    def ts(self):
        if self.step == A:
            st['p'] = profile(activities=[ProfilerActivity.CPU], with_stack=True); st['p'].__enter__()
        r = orig(self)
        if self.step == B:
            p = st['p']; p.__exit__(None, None, None)
            print(p.key_averages().table(sort_by="self_cpu_time_total", row_limit=40), flush=True)
            print(p.key_averages(group_by_stack_n=6).table(sort_by="self_cpu_time_total", row_limit=60, max_name_column_width=60), flush=True)
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    sys.argv = ['gsgs', 'run-job', sys.argv[3]]
    runpy.run_module('gsgs_engine', run_name='__main__')
