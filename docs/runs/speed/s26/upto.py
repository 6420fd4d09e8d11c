# Times steps 1..N of `gsgs run-job JOB` and exits: python upto.py N JOB_FOLDER (TAG labels the line; MODE=split runs
# torch's own ops on one thread and the compiled kernel's on two).
import runpy, sys, time, os
if __name__ == "__main__":
    import torch
    from gsgs_engine.train import trainer
    from gsgs_engine.render import cpu_backend
    MODE = os.environ.get("MODE", "")
    if MODE == "split":
        torch.set_num_threads(1)
        real = cpu_backend._ops
        class W:
            def __init__(self, o): self.o = o
            def __getattr__(self, name):
                f = getattr(self.o, name)
                if not callable(f): return f
                def g(*a, **k):
                    torch.set_num_threads(2)
                    try: return f(*a, **k)
                    finally: torch.set_num_threads(1)
                return g
        cache = {}
        def ops():
            if 'w' not in cache: cache['w'] = W(real())
            return cache['w']
        cpu_backend._ops = ops
        # the trainer sets threads? keep an eye
        orig_snt = torch.set_num_threads
    orig = trainer.Trainer.train_step
    N = int(sys.argv[1]); st = {}
    def ts(self):
        if self.step == 0:
            st['t0'] = time.perf_counter()
            if MODE == "split": torch.set_num_threads(1)
        r = orig(self)
        if self.step == N:
            dt = time.perf_counter() - st['t0']
            print(f"RESULT {os.environ.get('TAG','')} steps {N} seconds {dt:.2f} gaussians {self.model.num_gaussians} loss {self.last_losses['loss']:.6f} threads {torch.get_num_threads()}", flush=True)
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    job = sys.argv[2]
    sys.argv = ['gsgs', 'run-job', job]
    runpy.run_module('gsgs_engine', run_name='__main__')
