cd /tmp
for scene in "blender blender_lego" "llff llff_flower"; do set -- $scene
for T in before after; do
  if [ $T = before ]; then P=/tmp/s26/before; else P=/work/main; fi
  rm -rf /tmp/s26/cells_$T_$2
  PYTHONPATH=$P OMP_NUM_THREADS=2 /work/main/.venv/bin/python -m gsgs_engine bench sparse --protocol $1 --scene $2 --seeds 1 --variants '{"auto": {"prior": "auto"}}' --data-root /work/shared/data --work /tmp/s26/cells_${T}_$2 --doc /tmp/s26/cells_${T}_$2.md > /tmp/s26/cells_${T}_$2.log 2>&1
  python3 -c "
import json,glob
f=glob.glob('/tmp/s26/cells_${T}_$2/**/metrics.json',recursive=True)[0]; d=json.load(open(f))
print('$T $2', round(d['train_seconds'],1), d['psnr'], d['num_gaussians'], {k:round(v,1) for k,v in d['kernel_seconds'].items() if k in ('raster_forward','raster_backward','binning')})"
done; done
