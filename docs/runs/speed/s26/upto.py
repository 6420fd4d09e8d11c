import runpy, sys, time, os
if __name__ == "__main__":
    from gsgs_engine.train import trainer
    orig = trainer.Trainer.train_step
    N = int(sys.argv[1]); st = {}
    def ts(self):
        if self.step == 0: st['t0'] = time.perf_counter()
        r = orig(self)
        if self.step == N:
            dt = time.perf_counter() - st['t0']
            print(f"RESULT {os.environ.get('TAG','')} steps {N} seconds {dt:.2f} gaussians {self.model.num_gaussians} loss {self.last_losses['loss']:.6f}", flush=True)
            os._exit(0)
        return r
    trainer.Trainer.train_step = ts
    job = sys.argv[2]
    sys.argv = ['gsgs', 'run-job', job]
    runpy.run_module('gsgs_engine', run_name='__main__')
