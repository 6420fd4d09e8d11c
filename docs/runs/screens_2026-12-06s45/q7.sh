#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "s45/q[12345689].sh" > /dev/null; do sleep 10; done
export GSGS_SCREEN_ATTR_LR=3
/tmp/s45/cell.sh llff_flower llff attr3 0-0 '{"prior": "auto"}'
/tmp/s45/cell.sh llff_horns llff attr3 0-0 '{"prior": "auto"}'
