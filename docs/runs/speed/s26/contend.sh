run() { # tag env...
  local tag=$1; shift
  d=$(mktemp -d /tmp/gsgs_ab.XXXX); cp $(dirname $0)/lego_job.json $d/job.json
  env TAG=$tag OMP_NUM_THREADS=2 "$@" /work/main/.venv/bin/python $(dirname $0)/upto.py 300 $d 2>&1 | grep RESULT; rm -rf $d
}
for r in 1 2; do
for pol in passive spin1e6; do
  if [ $pol = spin1e6 ]; then E="GOMP_SPINCOUNT=1000000"; else E="GSGS_X=1"; fi
  echo "== two concurrent, $pol"; run two_$pol $E & run two_$pol $E; wait
  echo "== with hog, $pol"; (timeout 120 python3 -c "while 1: pass" &) ; run hog_$pol $E; pkill -f "while 1: pass"
done; done
