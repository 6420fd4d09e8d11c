#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[1234].sh" > /dev/null; do sleep 10; done
/tmp/s45/cell.sh llff_flower llff black 0-0 '{"prior": "auto", "background": [0, 0, 0]}'
/tmp/s45/cell.sh llff_horns llff black 0-0 '{"prior": "auto", "background": [0, 0, 0]}'
