P=/tmp/s36/pan
best() { # 4d_run candidates... -> prints "run model" of the highest stored static psnr
python - "$@" <<'PY'
import json,sys
c=[]
for a in sys.argv[1:]:
    run,model=a.split(":")
    c.append((json.load(open(run+"/results.json"))[model]["psnr"],run,model))
print(*max(c)[1:])
PY
}
args=()
for s in 0 1 2; do
  for c in 3 6 9; do
    read r m < <(best $P/sph01_c${c}_s$s:static_per_frame $P/pf100sph01_c${c}_s$s:static_per_frame $P/sph01_c${c}_s$s:static_all)
    args+=($c 0 $P/sph01_c${c}_s$s $r $m)
  done
done
for c in 3 6 9; do
  read r m < <(best $P/w10_c${c}_s0:static_per_frame $P/w10pf100_c${c}_s0:static_per_frame $P/w10_c${c}_s0:static_all)
  args+=($c 10 $P/w10_c${c}_s0 $r $m)
done
for s in 0 1 2; do
  read r m < <(best $P/w20fb_c3_s$s:static_per_frame $P/w20fbpf100_c3_s$s:static_per_frame $P/w20_c3_s$s:static_all)
  args+=(3 20 $P/w20_c3_s$s $r $m)
  for c in 6 9; do
    read r m < <(best $P/w20_c${c}_s$s:static_per_frame $P/w20pf100_c${c}_s$s:static_per_frame $P/w20_c${c}_s$s:static_all)
    args+=($c 20 $P/w20_c${c}_s$s $r $m)
  done
done
/work/main/.venv/bin/python /work/main/docs/runs/panoptic/s38/oracle.py "${args[@]}" --json /work/main/docs/runs/panoptic/s38/oracle.jsonl
