# usage: J=lego_job.json|flower_job.json N=400 ROUNDS="1 2" POLS="unset spin1e6" bash ab_omp2.sh (from any folder; the venv at /work/main/.venv)
J=${J:-$(dirname $0)/lego_job.json}; N=${N:-400}
for r in ${ROUNDS:-1 2 3}; do
for pol in ${POLS:-unset spin1e7 ACTIVE}; do
  rm -rf /tmp/gsgs_ab_job && mkdir /tmp/gsgs_ab_job && cp $J /tmp/gsgs_ab_job/job.json
  case $pol in
   unset) env TAG=$pol OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N /tmp/gsgs_ab_job 2>&1 | grep RESULT;;
   spin1e7) env TAG=$pol GOMP_SPINCOUNT=10000000 OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N /tmp/gsgs_ab_job 2>&1 | grep RESULT;;
   spin3e5) env TAG=$pol GOMP_SPINCOUNT=300000 OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N /tmp/gsgs_ab_job 2>&1 | grep RESULT;;
   spin1e6) env TAG=$pol GOMP_SPINCOUNT=1000000 OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N /tmp/gsgs_ab_job 2>&1 | grep RESULT;;
   ACTIVE) env TAG=$pol OMP_WAIT_POLICY=ACTIVE OMP_NUM_THREADS=2 /work/main/.venv/bin/python $(dirname $0)/upto.py $N /tmp/gsgs_ab_job 2>&1 | grep RESULT;;
  esac
done; done
