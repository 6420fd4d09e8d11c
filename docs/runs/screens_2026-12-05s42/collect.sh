#!/bin/bash
# copy finished cells' metrics.json into the docs folder as PROTOCOL_SCENE_VARIANT_seedN.json (table.py's naming)
D=/work/main/docs/runs/screens_2026-12-05s42
cd /tmp/s42/runs && for f in */*/*/seed*/result/metrics.json; do
  IFS=/ read -r p s v seed _ <<< "$f"; cp "$f" "$D/${p}_${s}_${v}_${seed}.json"; done
