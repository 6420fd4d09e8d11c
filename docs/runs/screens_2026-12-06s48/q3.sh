#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
GSGS_ORACLE_INIT=1 $C llff_flower llff oracle 0-0 '{"prior": "auto"}' /tmp/s48/tree2
GSGS_ORACLE_INIT=1 $C llff_horns llff oracle 0-0 '{"prior": "auto"}' /tmp/s48/tree2
