#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[123456].sh" > /dev/null; do sleep 10; done
for K in 1 2; do
/tmp/s45/cell.sh llff_flower llff black $K-$K '{"prior": "auto", "background": [0, 0, 0]}'
/tmp/s45/cell.sh llff_horns llff black $K-$K '{"prior": "auto", "background": [0, 0, 0]}'
done
