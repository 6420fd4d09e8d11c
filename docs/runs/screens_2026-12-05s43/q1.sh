#!/bin/bash
cd /work/main
for r in 1 2; do .venv/bin/gsgs bench rasterizer --sizes 50000 --resolutions 200 --threads 1,2 --backends cpu --repeats 7 >> /tmp/s43/raster.log 2>&1; done
C=/tmp/s43/cell.sh
for S in blender_lego blender_chair; do
  $C $S blender base 0-0 '{"prior": "auto"}'
  GSGS_S43_OPAC=0.3 $C $S blender op03 0-0 '{"prior": "auto"}'
  GSGS_S43_OPAC=0.5 $C $S blender op05 0-0 '{"prior": "auto"}'
  GSGS_S43_SCALE=0.5 $C $S blender sc05 0-0 '{"prior": "auto"}'
done
for S in llff_flower llff_horns; do
  $C $S llff base 0-0 '{"prior": "auto"}'
  GSGS_S43_OPAC=0.3 $C $S llff op03 0-0 '{"prior": "auto"}'
done
