#!/bin/bash
# copies every finished cell's metrics.json of /tmp/s47/runs here as SCENE_TAG_seedK.metrics.json
for p in /tmp/s47/runs/*/*/*/seed*/result/metrics.json; do
  IFS=/ read -r _ _ _ _ _ scene tag seed _ _ <<< "$p"
  cp "$p" "$(dirname "$0")/${scene}_${tag}_${seed}.metrics.json"
done
