#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
while pgrep -f "q3.sh" >/dev/null; do sleep 10; done
GSGS_SCREEN_OPACITY_LR=0.5 /tmp/s46/cell.sh llff_flower llff opac05 0-0 '{"prior": "auto"}'
