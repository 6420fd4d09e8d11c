#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s48/initcache
C=/tmp/s48/cell.sh
while pgrep -f q3.sh > /dev/null; do sleep 5; done
GSGS_ORACLE_INIT=vis $C llff_flower llff oraclevis 0-0 '{"prior": "auto"}' /tmp/s48/tree2
GSGS_ORACLE_INIT=vis $C llff_horns llff oraclevis 0-0 '{"prior": "auto"}' /tmp/s48/tree2
