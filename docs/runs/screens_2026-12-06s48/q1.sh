#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
$C llff_flower llff base 0-0 '{"prior": "auto"}'
$C llff_horns llff base 0-0 '{"prior": "auto"}'
