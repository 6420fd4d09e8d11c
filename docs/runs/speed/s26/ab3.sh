J=${J:-$(dirname $0)/lego_job.json}; N=${N:-400}
for r in ${ROUNDS:-1 2 3}; do
for pol in ${POLS:-passive split spin1e6}; do
  d=$(mktemp -d /tmp/gsgs_ab.XXXX); cp $J $d/job.json
  case $pol in
   passive) env TAG=$pol OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N $d 2>&1 | grep RESULT;;
   split) env TAG=$pol MODE=split OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N $d 2>&1 | grep RESULT;;
   spin1e6) env TAG=$pol GOMP_SPINCOUNT=1000000 OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N $d 2>&1 | grep RESULT;;
  esac
  rm -rf $d
done; done
