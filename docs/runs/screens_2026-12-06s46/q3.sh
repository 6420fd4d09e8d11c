#!/bin/bash
export GSGS_INIT_CACHE=/tmp/s45/initcache
GSGS_SCREEN_OPACITY_LR=2 /tmp/s46/cell.sh llff_flower llff opac2 0-0 '{"prior": "auto"}'
GSGS_SCREEN_OPACITY_LR=2 /tmp/s46/cell.sh llff_horns llff opac2 0-0 '{"prior": "auto"}'
/tmp/s46/cell.sh llff_flower llff pos05 0-0 '{"prior": "auto", "position_lr_scale": 0.5}'
/tmp/s46/cell.sh llff_horns llff pos05 0-0 '{"prior": "auto", "position_lr_scale": 0.5}'
