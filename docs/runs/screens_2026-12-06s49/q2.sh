#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s49/initcache
export GSGS_MVS_FILL=0.5
/tmp/s49/cell.sh llff_horns llff fill05 0-0 '{"prior": "auto"}'
