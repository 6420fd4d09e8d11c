# Python-level torch calls of steps A..B of `gsgs run-job JOB`, timed per calling line (session 31): python step_torch_calls.py A B JOB_FOLDER
import runpy, sys, os, collections, time, traceback
if __name__ == "__main__":
    import torch
    from torch.overrides import TorchFunctionMode
    from gsgs_engine.train import trainer
    A, B = int(sys.argv[1]), int(sys.argv[2]); st = {}
    agg = collections.Counter(); cnt = collections.Counter()
    class M(TorchFunctionMode):
        depth = 0
        def __torch_function__(self, func, types, args=(), kwargs=None):
            kwargs = kwargs or {}
            if M.depth: return func(*args, **kwargs)
            M.depth += 1
            t = time.perf_counter()
            try: return func(*args, **kwargs)
            finally:
                dt = time.perf_counter() - t; M.depth -= 1
                f = sys._getframe(1)
                while f and ("torch/" in f.f_code.co_filename and "gsgs" not in f.f_code.co_filename): f = f.f_back
                where = f"{f.f_code.co_filename.split('gsgs_engine/')[-1]}:{f.f_lineno}" if f else "?"
                k = (getattr(func, "__name__", str(func)), where); agg[k] += dt; cnt[k] += 1
    orig = trainer.Trainer.train_step
    def ts(self):
        if self.step == A: st['m'] = M(); st['m'].__enter__(); st['t'] = time.perf_counter()
        r = orig(self)
        if self.step == B:
            st['m'].__exit__(None, None, None); tot = time.perf_counter() - st['t']; n = B - A
            print(f"total {tot/n*1e3:.1f} ms/step")
            for (name, where), s in agg.most_common(40):
                print(f"{s/n*1e3:8.3f} ms/step {cnt[(name, where)]/n:5.1f}/step {name:24s} {where}")
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    sys.argv = ['gsgs', 'run-job', sys.argv[3]]
    runpy.run_module('gsgs_engine', run_name='__main__')
